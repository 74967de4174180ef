"""The generated building of ``bench/building.py``: its frames and edges, the corridor's surveys,
shared targets, determinism, and a plannable in-room query."""

from __future__ import annotations

import math

import pytest

from bench.building import (
    Building,
    body,
    build,
    camera,
    feature,
    image,
    marker,
    room,
    tracker,
)
from ubitrack_agent.graph.planner import Query, plan


@pytest.mark.parametrize(
    ("shape", "frames", "edges"),
    [
        # B + R0, M0, F0_1..5, T0, H0_1, C0_1, I0_1 / B->R0, R0->M0, 5 M0->F, R0->T0, T0->H0_1,
        # C0_1->H0_1, C0_1->I0_1, 5 I0_1->F
        (Building(), 12, 16),
        # two more trackers (R0->T, T->H each)
        (Building(redundant=2), 14, 20),
        # per room R, M, 5 F, 2 T, 3 H, C, I = 14 frames; edges B->R, R->M, 5 M->F, 2 R->T,
        # 6 T->H, C->H, C->I, 5 I->F = 22
        (Building(rooms=2, bodies=3, redundant=1), 1 + 2 * 14, 2 * 22),
        # 50 rooms of 13 frames and 20 edges
        (Building(rooms=50, redundant=2), 651, 1000),
        # two cameras without features: R, M, T, 2 H, 2 C, 2 I; B->R, R->M, R->T, 2 T->H,
        # 2 C->H, 2 C->I
        (Building(bodies=2, cameras=2, features=0), 1 + 9, 9),
        # a corridor adds one survey between neighbours
        (Building(rooms=3, layout="corridor"), 1 + 3 * 11, 3 * 16 + 2),
        # shared targets: each camera but the last room's sees 5 more features
        (Building(rooms=3, shared_targets=True), 1 + 3 * 11, 3 * 16 + 2 * 5),
    ],
)
def test_frame_and_edge_counts(shape: Building, frames: int, edges: int) -> None:
    srg = build(shape)
    assert (srg.number_of_nodes(), srg.number_of_edges()) == (frames, edges)


def test_every_room_hangs_off_the_building_and_its_trackers_track_every_body() -> None:
    srg = build(Building(rooms=2, bodies=2, redundant=1))
    for r in range(2):
        assert srg.has_edge("B", room(r))
        for k in range(2):
            assert srg.has_edge(room(r), tracker(r, k))
            for j in (1, 2):
                (data,) = srg.get_edge_data(tracker(r, k), body(r, j)).values()
                assert (data["type"], data["static"], data["provider"]) == (
                    "6D",
                    False,
                    tracker(r, k),
                )
    assert tracker(0, 0) == "T0" and tracker(0, 1) == "T0_1"


def test_the_corridor_adds_exactly_the_surveys_between_neighbours() -> None:
    star = build(Building(rooms=4))
    corridor = build(Building(rooms=4, layout="corridor"))
    extra = set(corridor.edges(keys=True)) - set(star.edges(keys=True))
    assert {(u, v) for u, v, _ in extra} == {(room(r), room(r + 1)) for r in range(3)}
    assert set(star.edges(keys=True)) <= set(corridor.edges(keys=True))
    for u, v, key in extra:
        data = corridor.edges[u, v, key]
        assert (data["type"], data["static"], data["provider"]) == ("6D", True, "database")


def test_shared_targets_each_camera_sees_the_next_rooms_marker() -> None:
    rooms = 3
    srg = build(Building(rooms=rooms, shared_targets=True))
    for r in range(rooms):
        seen = {v for v in srg.successors(image(r)) if v.startswith("F")}
        own = {feature(r, f) for f in range(1, 6)}
        nxt = {feature(r + 1, f) for f in range(1, 6)} if r + 1 < rooms else set()
        assert seen == own | nxt
        for f in nxt:
            (data,) = srg.get_edge_data(image(r), f).values()
            assert (data["type"], data["provider"]) == ("2D", camera(r))
            assert srg.has_edge(marker(r + 1), f)


def test_the_same_shape_builds_the_same_srg() -> None:
    shape = Building(rooms=3, bodies=2, redundant=1, layout="corridor", shared_targets=True)
    first, second = build(shape), build(shape)
    assert list(first.edges(keys=True, data=True)) == list(second.edges(keys=True, data=True))
    assert list(first.nodes) == list(second.nodes)


@pytest.mark.parametrize(
    "arguments",
    [
        {"layout": "ring"},
        {"rooms": 0},
        {"bodies": 0},
        {"redundant": -1},
        {"features": -1},
        {"cameras": 2},
    ],
)
def test_invalid_shapes_are_refused(arguments: dict) -> None:
    with pytest.raises(ValueError):
        Building(**arguments)


def test_the_in_room_query_plans_from_measured_edges_of_the_building(templates) -> None:
    srg = build(Building())
    query = Query(camera(0), marker(0), "6D")
    best = plan(srg, templates, query)[0]
    assert (best.edge.source, best.edge.target, best.edge.type) == (camera(0), marker(0), "6D")
    assert best.steps and math.isfinite(best.cost)
    measured = {(e.source, e.target, e.type) for e in best.measured()}
    assert measured <= {(u, v, d["type"]) for u, v, d in srg.edges(data=True)}
    # the camera's pose relative to the marker needs the camera's link to its body or image
    assert any(camera(0) in (source, target) for source, target, _ in measured)
