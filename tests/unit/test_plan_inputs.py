"""The documents ``ubitrack plan`` reads: formats told apart, static-edges entries and scenarios
turned into SRG edges as the live agent makes them, and the merge rule."""

from __future__ import annotations

import re

import numpy as np
import pytest
import yaml

from ubitrack_agent.commands.plan_inputs import (
    FORMATS,
    PlanEdge,
    build_srg,
    document_kind,
    load_plan_srg,
    merge,
    scenario_edges,
    setup_edges,
    stored_edges,
)
from ubitrack_agent.graph.srg import DEFAULT_SIGMA, SetupError
from ubitrack_agent.sim_trackers.scenario import DEFAULT_SCENARIO

COVARIANCE = np.diag([1e-6] * 3 + [4e-8] * 3).tolist()  # rotation (rad^2) first, then m^2
STORED_C_HT = {
    "from": "C",
    "to": "HT",
    "type": "6D",
    "rotation": [0.7071, 0.0, 0.0, 0.7071],  # typed with four decimals: normalised
    "translation": [0.03, -0.06, 0.04],
    "covariance": COVARIANCE,
    "provenance": {"flow": "averaging-1a2b", "samples": 212},
}
STORE = {
    "provider": "store",
    "edges": [STORED_C_HT, {"from": "WT", "to": "F1", "type": "3D", "position": [0, -0.2, 0]}],
}
SETUP = {
    "edges": [
        {"from": "ART", "to": "HT", "type": "6D", "provider": "ART"},
        {"from": "C", "to": "HT", "type": "6D", "static": True},
        {"from": "C", "to": "HT", "type": "6D", "provider": "cam"},  # dynamic: kept
        {"from": "HT", "to": "C", "type": "6D", "static": True},  # the other way round: kept
    ]
}


@pytest.mark.parametrize(
    ("document", "kind"),
    [
        (SETUP, "setup"),
        ({"name": "x", "edges": []}, "setup"),
        (STORE, "static-edges"),
        ({"provider": "db"}, "static-edges"),  # its reader names what is missing
        (yaml.safe_load(DEFAULT_SCENARIO.read_text(encoding="utf-8")), "scenario"),
    ],
)
def test_the_format_is_told_by_the_top_level_keys(document, kind):
    assert document_kind(document, "f.yaml") == kind


@pytest.mark.parametrize("document", [None, [1, 2], {"colour": "red"}, "edges"])
def test_an_unrecognised_document_names_the_accepted_formats(document):
    expected = f"f.yaml: not a document ubitrack plan reads; expected {FORMATS}"
    with pytest.raises(SetupError, match=re.escape(expected)):
        document_kind(document, "f.yaml")
    assert all(name in FORMATS for name in ("setup file", "static-edges file", "scenario"))


def test_a_static_edges_entry_is_a_measured_static_edge_of_its_provider():
    pose, point = stored_edges(STORE, "store.yaml")
    assert pose.where == "store.yaml: edges[0]" and pose.stored
    assert pose.entry == {
        "from": "C",
        "to": "HT",
        "type": "6D",
        "static": True,
        "mode": "push",
        "sigma": pytest.approx((3e-6 + 1.2e-7) ** 0.5),  # as the store announces it
        "id": "store/C_HT",  # as the live agent names it
        "provider": "store",
    }
    assert "sigma" not in point.entry and point.entry["id"] == "store/WT_F1"  # no covariance


def test_a_bad_static_edges_file_is_a_setup_error_naming_the_entry():
    bad = {"provider": "store", "edges": [STORED_C_HT | {"rotation": [0, 0, 0, 2]}]}
    with pytest.raises(SetupError, match=r"store\.yaml: edges\[0\] \(C->HT 6D\).*normalise it"):
        stored_edges(bad, "store.yaml")
    loop = {"provider": "store", "edges": [STORED_C_HT | {"to": "C"}]}
    with pytest.raises(SetupError, match=r"store\.yaml: .*must join two different frames"):
        stored_edges(loop, "store.yaml")


def test_a_stored_edge_replaces_the_static_setup_edges_of_its_relation():
    edges = [*setup_edges(SETUP, "setup.yaml"), *stored_edges(STORE, "store.yaml")]
    kept, notes = merge(edges)
    assert [edge.where for edge in kept] == [
        "setup.yaml: edges[0]",
        "setup.yaml: edges[2]",
        "setup.yaml: edges[3]",
        "store.yaml: edges[0]",
        "store.yaml: edges[1]",
    ]
    assert notes == ["store.yaml: edges[0] C->HT 6D (provider store) replaces setup.yaml: edges[1]"]


def test_the_same_relation_stored_twice_is_an_error_naming_both():
    other = {"provider": "db", "edges": [STORED_C_HT]}
    edges = [*stored_edges(STORE, "store.yaml"), *stored_edges(other, "db.yaml")]
    with pytest.raises(SetupError) as info:
        merge(edges)
    assert str(info.value) == (
        "store.yaml: edges[0] and db.yaml: edges[0]: C->HT 6D is stored in two static-edges "
        "files; give one of them"
    )


def test_a_scenario_gives_the_edges_its_simulators_announce():
    edges = {edge.relation: edge for edge in scenario_edges(str(DEFAULT_SCENARIO))}
    tracked, room, feature = (
        edges["ART", "HT", "6D"],
        edges["ART", "WT", "6D"],
        edges["IP", "F1", "2D"],
    )
    assert tracked.entry["provider"] == "ART" and not tracked.entry["static"]
    # 0.3 mm and 0.05 degrees per axis: the expected error at a 1 m lever arm
    body_sigma = (3 * 0.0003**2 + 3 * np.radians(0.05) ** 2) ** 0.5
    assert tracked.entry["rate"] == 60 and tracked.entry["sigma"] == pytest.approx(body_sigma)
    assert room.entry["static"] and room.where.endswith("paper_figure1.yaml: art: ART_WT")
    assert feature.entry["provider"] == "camera" and feature.entry["id"] == "camera/IP_F1"
    database = [edge for edge in edges.values() if edge.entry["provider"] == "database"]
    assert {edge.relation for edge in database} >= {("WT", "A", "6D"), ("C", "IP", "3x4")}
    assert ("C", "HT", "6D") not in edges  # the default scenario calibrates it live
    assert all(edge.entry["static"] and not edge.stored for edge in database)


def test_files_of_every_format_merge_into_one_srg(tmp_path):
    paths = []
    for name, document in (("setup.yaml", SETUP), ("store.yaml", STORE)):
        paths.append(str(tmp_path / name))
        (tmp_path / name).write_text(yaml.safe_dump(document), encoding="utf-8")
    srg, notes = load_plan_srg([str(DEFAULT_SCENARIO), *paths])
    assert [note.split(" replaces ")[1] for note in notes] == [
        f"{DEFAULT_SCENARIO}: database: WT_F1",
        f"{tmp_path / 'setup.yaml'}: edges[1]",
    ]
    static_c_ht = {
        key: data["provider"]
        for _, target, key, data in srg.out_edges("C", keys=True, data=True)
        if target == "HT" and data["static"]
    }
    assert static_c_ht == {"store/C_HT": "store"}
    assert srg.edges["WT", "F1", "store/WT_F1"]["quality"].variance == DEFAULT_SIGMA**2
    assert srg.edges["C", "HT", "store/C_HT"]["quality"].variance == pytest.approx(3.12e-6)


def test_an_edge_id_used_in_two_documents_is_named():
    edges = [
        PlanEdge("a.yaml: edges[0]", {"from": "A", "to": "B", "type": "6D", "id": "x"}),
        PlanEdge("b.yaml: edges[0]", {"from": "B", "to": "C", "type": "6D", "id": "x"}),
    ]
    with pytest.raises(SetupError, match=r"b\.yaml: edges\[0\]: .*duplicate edge id 'x'"):
        build_srg(edges, "test")
