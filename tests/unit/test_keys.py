"""Query, relation and progress keys: the kind chunk (static, dynamic, recalibrate)."""

from __future__ import annotations

import pytest

from ubitrack_agent.net.keys import KINDS, KeySpace, RelationId

KEYS = KeySpace("ubitrack/test")
RECALIBRATE = RelationId("C", "HT", "6D", static=True, recalibrate=True)


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_query_and_relation_keys_round_trip_every_kind(kind):
    relation = RelationId("C", "HT", "6D", *KINDS[kind])
    assert relation.kind == kind
    assert KEYS.relation(relation) == f"ubitrack/test/relation/C/HT/6D/{kind}"
    assert KEYS.parse_relation(KEYS.relation(relation)) == relation
    key = KEYS.query(relation, "app1", "hmd")
    assert key == f"ubitrack/test/query/C/HT/6D/{kind}/hmd/app1"
    assert KEYS.parse_query(key) == (relation, "app1", "hmd", frozenset())
    labelled = KEYS.query(relation, "app1", "hmd", frozenset({"gpu", "display"}))
    assert labelled == f"ubitrack/test/query/C/HT/6D/{kind}/hmd/app1/display+gpu"
    assert KEYS.parse_query(labelled) == (relation, "app1", "hmd", {"gpu", "display"})
    token = KEYS.parse_token("query", key)
    assert (token.name, token.relation, token.host) == ("app1", relation, "hmd")


def test_a_recalibration_has_keys_apart_from_the_static_relation():
    static = RelationId("C", "HT", "6D", static=True)
    assert static != RECALIBRATE
    assert KEYS.relation(RECALIBRATE) != KEYS.relation(static)
    assert KEYS.progress(RECALIBRATE) == "ubitrack/test/progress/C/HT/6D/recalibrate"
    assert KEYS.progress(static) == "ubitrack/test/progress/C/HT/6D/static"
    assert str(RECALIBRATE) == "C->HT:6D recalibrate"


def test_a_recalibration_is_of_a_static_relation():
    with pytest.raises(ValueError, match="static=True"):
        RelationId("C", "HT", "6D", recalibrate=True)


@pytest.mark.parametrize(
    "key, message",
    [
        ("ubitrack/test/query/C/HT/6D/recal/h/app", "kind 'recal'"),
        ("ubitrack/test/query/C/HT/6D/Static/h/app", "kind 'Static'"),
        ("ubitrack/test/query/C/HT/6D/recalibrate/app", "expected query/"),
        ("ubitrack/test/query/C/HT/6D/recalibrate/h/app/x/y", "expected query/"),
        ("ubitrack/test/query/C/HT/6D/recalibrate/h/app/a++b", "no label"),
        ("ubitrack/test/query/C/HT/6D/recalibrate/h/app/a:b", "no label"),
        ("ubitrack/test/query/C/HT/6D/recalibrate/*/app", "may only contain"),
        ("ubitrack/test/query/C/C/6D/recalibrate/h/app", "two different frames"),
        ("ubitrack/other/query/C/HT/6D/recalibrate/h/app", "not a query key"),
    ],
)
def test_malformed_query_keys_are_rejected(key, message):
    with pytest.raises(ValueError, match=message):
        KEYS.parse_query(key)


@pytest.mark.parametrize(
    "key", ["ubitrack/test/relation/C/HT/6D/again", "ubitrack/test/relation/C/HT/recalibrate"]
)
def test_malformed_relation_keys_are_rejected(key):
    with pytest.raises(ValueError):
        KEYS.parse_relation(key)


def test_a_liveness_report_key_is_one_chunk_below_data_apart_from_every_edge_key():
    key = KEYS.liveness("art")
    assert key == "ubitrack/test/data/art"
    assert KEYS.parse_liveness(key) == "art"
    edge = KEYS.measured("art", "ART_HT")
    assert edge.startswith(key + "/")  # the provider's edges lie below its report key
    with pytest.raises(ValueError):
        KEYS.parse_liveness(edge)  # two chunks: an edge's data, not a report
    with pytest.raises(ValueError):
        KEYS.liveness("a/b")
    with pytest.raises(ValueError):
        KEYS.parse_liveness("ubitrack/other/data/art")
