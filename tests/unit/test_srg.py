"""SRG model and setup files (paper section 2)."""

from __future__ import annotations

import pytest

from ubitrack_agent.graph.srg import (
    SetupError,
    add_measured_edge,
    check_node_name,
    load_setup,
    new_srg,
    parse_setup,
    remove_provider,
    remove_static_relation,
    static_relation_edges,
)
from ubitrack_agent.net.keys import validate_key_chunks


def test_paper_setup_has_figure_1_frames_and_attributes(tracking_setup):
    assert set(tracking_setup.nodes) == {
        "ART",
        "WT",
        "HT",
        "C",
        "IP",
        "A",
        "F1",
        "F2",
        "F3",
        "F4",
        "F5",
    }
    art_wt = tracking_setup.edges["ART", "WT", "ART->WT:6D"]
    assert art_wt["static"] is True and art_wt["measured"] is True
    assert art_wt["provider"] == "database"
    art_ht = tracking_setup.edges["ART", "HT", "ART->HT:6D"]
    assert art_ht["static"] is False and art_ht["mode"] == "push"
    assert art_ht["sources"] == frozenset({"ART->HT:6D"})
    assert tracking_setup.edges["C", "IP", "C->IP:3x4"]["type"] == "3x4"


def test_calibration_setup_lacks_camera_to_head_target(calibration_setup, tracking_setup):
    assert not calibration_setup.has_edge("C", "HT")
    assert tracking_setup.number_of_edges() - calibration_setup.number_of_edges() == 1


def test_parallel_edges_get_distinct_ids():
    srg = parse_setup({"edges": [{"from": "A", "to": "B", "type": "6D"}] * 2})
    assert sorted(k for _, _, k in srg.edges(keys=True)) == ["A->B:6D", "A->B:6D#2"]


def test_quality_fields_are_read():
    srg = parse_setup(
        {
            "edges": [
                {"from": "A", "to": "B", "type": "6D", "sigma": 0.002, "rate": 60, "latency": 0.01}
            ]
        }
    )
    quality = srg.edges["A", "B", "A->B:6D"]["quality"]
    assert quality.variance == pytest.approx(4e-6)
    assert (quality.rate, quality.latency) == (60.0, 0.01)


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ({"from": "A", "to": "B", "type": "6D", "colour": "red"}, "unknown field(s) ['colour']"),
        ({"from": "A", "to": "B", "type": "7D"}, "unknown type '7D'"),
        ({"from": "A", "to": "B", "type": "6D", "static": "yes"}, "field 'static'"),
        ({"from": "A", "type": "6D"}, "missing field 'to'"),
        ({"from": "A", "to": "B", "type": "6D", "sigma": -1}, "in [0, 1000], got -1"),
        ({"from": "A", "to": "B", "type": "6D", "mode": "poll"}, "unknown mode"),
        ({"from": "A", "to": "A", "type": "6D"}, "two different frames"),
        ({"from": "A/B", "to": "B", "type": "6D"}, "frame name 'A/B'"),
    ],
)
def test_bad_entries_name_file_entry_and_field(entry, message):
    with pytest.raises(SetupError) as info:
        parse_setup({"edges": [{"from": "X", "to": "Y", "type": "6D"}, entry]}, "setup.yaml")
    assert str(info.value).startswith("setup.yaml: edges[1]")
    assert message in str(info.value)


@pytest.mark.parametrize(
    "name", ["", "a/b", "a*", "a$", "a#", "a?", "a@b", "a b", "a\tb", 7, "Ä", "a,b", "a'b"]
)
def test_unsafe_frame_names_are_rejected(name):
    with pytest.raises(SetupError):
        check_node_name(name, "here")


@pytest.mark.parametrize("name", ["HT", "F1", "art.body-2", "a:b", "x=1", "Ä", "a,b", "a b", ""])
def test_a_frame_name_plans_offline_iff_it_works_in_keys(name):
    """One rule for planner and keys: a setup that plans offline also runs live."""
    try:
        check_node_name(name, "here")
        planned = True
    except SetupError:
        planned = False
    try:
        validate_key_chunks(name, single_chunk=True)
        keyed = True
    except ValueError:
        keyed = False
    assert planned == keyed


def test_top_level_errors(tmp_path):
    with pytest.raises(SetupError, match="unknown top-level key"):
        parse_setup({"edges": [{"from": "A", "to": "B", "type": "6D"}], "nodes": []})
    with pytest.raises(SetupError, match="non-empty list"):
        parse_setup({"edges": []})
    bad = tmp_path / "bad.yaml"
    bad.write_text("edges: [\n")
    with pytest.raises(SetupError, match=r"bad\.yaml: not valid YAML"):
        load_setup(bad)
    with pytest.raises(SetupError, match="cannot read"):
        load_setup(tmp_path / "missing.yaml")


def test_duplicate_explicit_id_is_rejected():
    srg = new_srg()
    add_measured_edge(srg, "A", "B", "6D", edge_id="e1")
    with pytest.raises(SetupError, match="duplicate edge id"):
        add_measured_edge(srg, "B", "C", "6D", edge_id="e1")


def test_remove_provider_drops_only_that_sensors_edges(tracking_setup):
    without = remove_provider(tracking_setup, "ART")
    assert not without.has_edge("ART", "HT")
    assert without.has_edge("ART", "WT")  # a database edge, not the tracker's
    assert without.number_of_edges() == tracking_setup.number_of_edges() - 1


def test_a_recalibration_plans_without_the_static_edges_of_its_relation(tracking_setup):
    srg = tracking_setup.copy()
    add_measured_edge(srg, "HT", "C", "6D", static=True, provider="store")  # either direction
    add_measured_edge(srg, "C", "HT", "3D", static=True, provider="store")  # any type
    add_measured_edge(srg, "C", "HT", "6D", provider="C")  # dynamic: kept
    ignored = ["C->HT:3D", "C->HT:6D", "HT->C:6D"]
    assert static_relation_edges(srg, "C", "HT") == static_relation_edges(srg, "HT", "C") == ignored
    without = remove_static_relation(srg, "HT", "C")
    assert [key for _, _, key in without.edges(keys=True)] == [
        key for _, _, key in srg.edges(keys=True) if key not in ignored
    ]
    assert without.has_edge("C", "HT", "C->HT:6D#2")
    assert srg.number_of_edges() == without.number_of_edges() + 3  # the SRG itself is untouched
    assert set(without.graph["edge_index"]) == {key for _, _, key in without.edges(keys=True)}


def test_a_frame_only_the_static_relation_reached_leaves_with_it():
    srg = new_srg()
    add_measured_edge(srg, "T", "M", "6D")
    add_measured_edge(srg, "M", "Tip", "3D", static=True)  # a stored tip calibration
    without = remove_static_relation(srg, "M", "Tip")
    assert set(without.nodes) == {"T", "M"}  # so the calibration may introduce Tip again
    assert remove_static_relation(srg, "T", "M").number_of_edges() == 2  # nothing static there
