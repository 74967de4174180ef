"""Pattern detection (section 5.1): occurrences, space and time expansion, bookkeeping."""

from __future__ import annotations

from dataclasses import replace

import pytest

from ubitrack_agent.graph.matcher import (
    EdgeIndex,
    expand_group,
    find_matches,
    group_key,
    independent,
)
from ubitrack_agent.graph.planner import Workspace
from ubitrack_agent.graph.srg import parse_setup


def index_of(edges, rigid=()):
    """An EdgeIndex of measured edges written as (from, to, type, static)."""
    srg = parse_setup(
        {"edges": [{"from": a, "to": b, "type": t, "static": s} for a, b, t, s in edges]}
    )
    ws = Workspace()
    for u, v, key, data in srg.edges(keys=True, data=True):
        ws.add_measured(u, v, key, data)
    for a, b in rigid:
        ws.index.add_rigid(a, b)
    return ws.index


def instances(template, index):
    groups = {}
    for match in find_matches(template, index):
        groups.setdefault(group_key(match), {})[match.edges] = match
    return [i for members in groups.values() for i in expand_group(list(members.values()), index)]


@pytest.fixture(scope="module")
def by_pattern(templates):
    return {t.name: t for t in templates}


def camera_setup(features, *, feature_static=True, image_dynamic=True):
    edges = [("C", "IP", "3x4", True)]
    for i in range(1, features + 1):
        edges.append(("IP", f"F{i}", "2D", not image_dynamic))
        edges.append(("WT", f"F{i}", "3D", feature_static))
    return edges


def test_inversion_matches_poses_and_rotations_only(by_pattern):
    index = index_of([("A", "B", "6D", False), ("B", "C", "3R", False), ("C", "D", "2D", False)])
    found = instances(by_pattern["inversion"], index)
    assert sorted(i.outputs[0][1:4] for i in found) == [("B", "A", "6D"), ("C", "B", "3R")]
    assert all(i.expansion == "none" for i in found)


def test_concatenation_binds_the_type_variable(by_pattern):
    index = index_of([("A", "B", "6D", True), ("B", "C", "3D", False), ("C", "D", "6D", False)])
    found = instances(by_pattern["concatenation"], index)
    # A->B (6D) with B->C (3D) gives A->C 3D; B->C 3D cannot be the first (pose) input.
    assert [i.outputs[0][1:5] for i in found] == [("A", "C", "3D", False)]


def test_space_expansion_of_2d3d_pose_estimation(by_pattern):
    found = instances(by_pattern["pose_estimation_2d3d"], index_of(camera_setup(5)))
    assert len(found) == 1
    (instance,) = found
    assert instance.expansion == "space"
    inputs = dict(instance.inputs)
    assert inputs["CI"] == ("C->IP:3x4",)
    assert len(inputs["IF"]) == len(inputs["OF"]) == 5
    assert instance.outputs[0][1:5] == ("C", "WT", "6D", False)


def test_too_few_correspondences_are_rejected(by_pattern):
    assert instances(by_pattern["pose_estimation_2d3d"], index_of(camera_setup(3))) == []


def test_time_expansion_needs_dynamic_correspondences_static_rest_and_rigid_output(by_pattern):
    template = by_pattern["pose_estimation_2d3d"]
    one_moving_point = camera_setup(1, feature_static=False)
    assert instances(template, index_of(one_moving_point)) == []  # C-WT not known rigid
    (instance,) = instances(template, index_of(one_moving_point, rigid=[("C", "WT")]))
    assert instance.expansion == "time"
    assert instance.outputs[0][4] is True  # time expansions yield static edges
    # a static correspondence edge forbids the time expansion
    assert instances(template, index_of(camera_setup(1), rigid=[("C", "WT")])) == []


def test_fusion_is_a_space_expansion_over_independent_parallel_edges(by_pattern):
    index = index_of([("A", "B", "6D", False), ("A", "B", "6D", False), ("A", "B", "6D", True)])
    found = instances(by_pattern["fusion"], index)
    assert {i.expansion for i in found} == {"space"}
    # all three, and the cheapest two (each fused estimate adds its sensor to the cost)
    assert sorted(len(dict(i.inputs)["AB"]) for i in found) == [2, 3]
    cheapest = min(index.edges.values(), key=lambda e: e.cost)
    (pair,) = (i for i in found if len(dict(i.inputs)["AB"]) == 2)
    assert cheapest.id in dict(pair.inputs)["AB"]
    assert all(i.outputs[0][4] is False for i in found)  # a dynamic input makes it dynamic


def test_fusion_rejects_estimates_sharing_a_measurement(by_pattern):
    index = index_of([("A", "B", "6D", False)])
    original = index.edges["A->B:6D"]
    index.add(replace(original, id="copy", measured=False, canon="x"))
    assert instances(by_pattern["fusion"], index) == []


def test_inputs_sharing_a_measured_edge_are_redundant(by_pattern):
    index = index_of([("A", "B", "6D", False), ("B", "C", "6D", False)])
    bc = index.edges["B->C:6D"]
    index.add(replace(bc, id="B->C derived from A->B", sources=frozenset({"A->B:6D"})))
    found = instances(by_pattern["concatenation"], index)
    assert [dict(i.inputs)["BC"] for i in found] == [("B->C:6D",)]


def test_inversion_of_an_inversion_is_not_matched(by_pattern):
    index = index_of([("A", "B", "6D", False)])
    ab = index.edges["A->B:6D"]
    index.add(replace(ab, id="B->A", source="B", target="A", pattern="Inversion"))
    found = instances(by_pattern["inversion"], index)
    assert [dict(i.inputs)["AB"] for i in found] == [("A->B:6D",)]


def test_averaging_needs_a_rigid_relation(by_pattern):
    dynamic = [("C", "HT", "6D", False)]
    assert instances(by_pattern["averaging"], index_of(dynamic)) == []
    (instance,) = instances(by_pattern["averaging"], index_of(dynamic, rigid=[("C", "HT")]))
    assert instance.expansion == "time"
    assert instance.outputs[0][4:] == (True, "pull")


def test_hand_eye_uses_rigid_links_between_hand_eye_and_base_object(by_pattern):
    edges = [("ART", "HT", "6D", False), ("C", "WT", "6D", False), ("ART", "WT", "6D", True)]
    assert instances(by_pattern["hand_eye_calibration"], index_of(edges)) == []
    found = instances(by_pattern["hand_eye_calibration"], index_of(edges, rigid=[("C", "HT")]))
    outputs = {frozenset(o[1:3] for o in i.outputs) for i in found}
    assert frozenset({("HT", "C"), ("ART", "WT")}) in outputs
    assert all(i.expansion == "time" for i in found)


def test_time_integrated_static_edges_may_share_dynamic_sources():
    index = index_of([("A", "B", "6D", False), ("B", "C", "6D", True)])
    ab, bc = index.edges["A->B:6D"], index.edges["B->C:6D"]
    averaged = replace(ab, id="avg", static=True, time_integrated=True, sources=ab.sources)
    assert independent(averaged, ab, index, strict=False)
    assert not independent(averaged, ab, index, strict=True)
    assert not independent(replace(averaged, time_integrated=False), ab, index, strict=False)
    with_static = replace(averaged, sources=ab.sources | bc.sources)
    assert not independent(with_static, bc, index, strict=False)


def test_seeded_search_only_finds_occurrences_using_a_seed(by_pattern):
    index = index_of([("A", "B", "6D", False), ("B", "C", "6D", False), ("C", "D", "6D", False)])
    seeded = {m.edges for m in find_matches(by_pattern["concatenation"], index, ["C->D:6D"])}
    assert seeded == {("B->C:6D", "C->D:6D")}
    assert len({m.edges for m in find_matches(by_pattern["concatenation"], index)}) == 2


def test_edge_index_tracks_measured_rigid_pairs():
    index = index_of([("A", "B", "6D", True), ("B", "C", "6D", False)])
    assert index.is_rigid("B", "A") and index.is_measured_rigid("A", "B")
    assert not index.is_rigid("B", "C")
    assert isinstance(index, EdgeIndex)


def test_3d3d_pose_estimation_space_and_time(by_pattern):
    template = by_pattern["pose_estimation_3d3d"]
    three_points = [(a, f"P{i}", "3D", a == "B") for a in ("A", "B") for i in range(3)]
    found = instances(template, index_of(three_points))
    # the roles are symmetric: both directions are found (planning keeps one, see canon)
    assert sorted(i.outputs[0][1:5] for i in found) == [
        ("A", "B", "6D", False),
        ("B", "A", "6D", False),
    ]
    assert all(i.expansion == "space" and len(dict(i.inputs)["AF"]) == 3 for i in found)
    # tracker alignment: one point tracked by two trackers over time (section 3.3)
    one_moving_point = [("A", "P", "3D", False), ("B", "P", "3D", False)]
    assert instances(template, index_of(one_moving_point)) == []
    found = instances(template, index_of(one_moving_point, rigid=[("A", "B")]))
    assert {i.expansion for i in found} == {"time"} and len(found) == 2
    assert all(i.outputs[0][4] is True for i in found)


def test_a_seed_that_cannot_be_a_copy_yet_waits_until_its_frame_has_enough_edges(by_pattern):
    """Where time expansions add nothing (``space_only``), an occurrence of 3D-3D pose
    estimation seeded at a frame with fewer edges than the least copies (A has two points, the
    pattern needs three) is held back, and found in the first seeded search after A has a
    third: over the rounds the searches find exactly the occurrences of one search over the
    final edges."""
    template = by_pattern["pose_estimation_3d3d"]
    edges = [("A", f"P{i}", "3D", False) for i in range(2)]
    edges += [("B", f"P{i}", "3D", False) for i in range(3)]
    srg = parse_setup(
        {"edges": [{"from": a, "to": b, "type": t, "static": s} for a, b, t, s in edges]}
    )
    ws = Workspace()
    for u, v, key, data in srg.edges(keys=True, data=True):
        ws.add_measured(u, v, key, data)
    ws.index.space_only = True
    first = {m.edges for m in find_matches(template, ws.index, list(ws.index.edges))}
    assert first and all(edges[0].startswith("B->") for edges in first)  # A in role A waits
    assert ws.index.waiting[template.name]
    ws.add_measured("A", "P2", "A->P2:3D", dict(srg.edges["B", "P2", "B->P2:3D"]))
    second = {m.edges for m in find_matches(template, ws.index, ["A->P2:3D"])}
    assert ("A->P0:3D", "B->P0:3D") in second  # held back, found now
    assert not ws.index.waiting[template.name]
    assert first | second == {m.edges for m in find_matches(template, ws.index)}
    # a time expansion is not formed where it can add nothing
    assert (
        expand_group(
            [m for m in find_matches(template, ws.index) if m.edges == ("A->P0:3D", "B->P0:3D")],
            ws.index,
        )
        == []
    )


def test_triangulation_over_image_planes(by_pattern):
    two_views = [("C", "I1", "3x4", True), ("C", "I2", "3x4", True)]
    two_views += [("I1", "F", "2D", False), ("I2", "F", "2D", False)]
    (instance,) = instances(by_pattern["triangulation_2d3d"], index_of(two_views))
    assert instance.expansion == "space"
    assert sorted(dict(instance.inputs)["CI"]) == ["C->I1:3x4", "C->I2:3x4"]
    assert instance.outputs[0][1:5] == ("C", "F", "3D", False)
    assert instances(by_pattern["triangulation_2d3d"], index_of(two_views[::2])) == []


def test_projective_calibration_needs_six_points(by_pattern):
    def points(n):
        return [
            e for i in range(n) for e in (("I", f"F{i}", "2D", False), ("C", f"F{i}", "3D", True))
        ]

    (instance,) = instances(by_pattern["projective_calibration"], index_of(points(6)))
    assert instance.expansion == "space"
    assert instance.outputs[0][1:4] == ("C", "I", "3x4")
    assert instances(by_pattern["projective_calibration"], index_of(points(5))) == []


def test_pose_split_has_two_outputs_and_only_splits_measured_poses(by_pattern):
    index = index_of([("A", "B", "6D", False)])
    (instance,) = instances(by_pattern["pose_split"], index)
    assert [o[1:4] for o in instance.outputs] == [("A", "B", "3D"), ("A", "B", "3R")]
    index.add(replace(index.edges["A->B:6D"], id="derived", measured=False, canon="d"))
    assert len(instances(by_pattern["pose_split"], index)) == 1


def test_tip_calibration_binds_its_introduced_role_to_a_new_frame_only(by_pattern):
    template = by_pattern["tip_calibration"]
    pointer = [("T", "M", "6D", False), ("T", "B", "6D", False), ("M", "N", "6D", True)]
    assert instances(template, index_of(pointer, rigid=[("M", "Tip")])) == []  # no new frame
    index = index_of(pointer, rigid=[("M", "Tip")])
    index.new_frames = ("Tip",)
    (instance,) = instances(template, index)  # the query's rigid pair says where Tip belongs
    assert instance.expansion == "time"
    assert dict(instance.inputs) == {"TM": ("T->M:6D",)}
    assert [o[1:5] for o in instance.outputs] == [
        ("M", "Tip", "3D", True),
        ("T", "Tip", "3D", True),
    ]
    pivot = index_of(pointer, rigid=[("T", "Tip")])
    pivot.new_frames = ("Tip",)
    assert sorted(dict(i.inputs)["TM"] for i in instances(template, pivot)) == [
        ("T->B:6D",),
        ("T->M:6D",),
    ]  # which body pivots is not known: each is an occurrence
    nothing_rigid = index_of(pointer)
    nothing_rigid.new_frames = ("Tip",)
    assert instances(template, nothing_rigid) == []  # no relation of Tip to keep


def test_an_introduced_role_binds_a_frame_distinct_from_the_other_roles(by_pattern):
    index = index_of([("T", "M", "6D", False)], rigid=[("T", "M")])
    index.new_frames = ("M",)  # (the planner passes only frames the SRG lacks)
    assert list(find_matches(by_pattern["tip_calibration"], index)) == []
