"""The planner's search against the exhaustive one it replaced (issue [scale], "the same
answers"): on generated setups small enough for the old search, the best derivation costs no
more than the old one's, the same queries are solvable, and the choice does not depend on the
order in which the SRG's edges were announced; parts planned once are shared across queries
and planned again when their edges change."""

from __future__ import annotations

import random

import networkx as nx
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from bench.building import Building, body, build, camera, marker, room, tracker
from tests.unit import exhaustive_planner, srg_strategies
from ubitrack_agent.graph.planner import (
    DEFAULT_PER_RELATION,
    DEFAULT_SLACK,
    STEP_WEIGHT,
    NoSolutionError,
    PartCache,
    PartNames,
    Query,
    _part_shape,
    _renamed,
    plan,
    saturate,
    solutions,
)
from ubitrack_agent.graph.srg import add_measured_edge, new_srg, remove_provider

TOLERANCE = 1e-9


def best_cost(planner, srg, templates, query, **options) -> float | None:
    try:
        return planner(srg, templates, query, **options)[0].cost
    except NoSolutionError:
        return None


def assert_no_worse(srg, templates, query, tolerance=TOLERANCE, allowance=0.0, **options):
    """The new search solves what the old one solves, at no higher cost (within ``tolerance``,
    relative, and ``allowance``, absolute)."""
    old = best_cost(exhaustive_planner.plan, srg, templates, query, **options)
    new = best_cost(plan, srg, templates, query, **options)
    assert (old is None) == (new is None), (query, old, new)
    if old is not None:
        assert new <= old * (1 + tolerance) + allowance, (query, old, new)


buildings = st.builds(
    Building,
    rooms=st.integers(1, 2),
    bodies=st.integers(1, 2),
    redundant=st.integers(0, 1),
    cameras=st.just(1),
    features=st.sampled_from([0, 4]),
    layout=st.sampled_from(["star", "corridor"]),
    shared_targets=st.booleans(),
)


def building_query(shape: Building, kind: str) -> Query:
    last = shape.rooms - 1
    if kind == "camera_marker":
        return Query(camera(0), marker(last), "6D")
    if kind == "head_head":
        target = body(last, 2) if last == 0 and shape.bodies > 1 else body(last)
        return Query(body(0), target if target != body(0) else room(0), "6D")
    return Query(camera(0), body(0), "6D", static=True)  # a calibration of the camera's mount


def too_big_for_the_old_search(shape: Building, kind: str) -> bool:
    """The shapes of ``buildings`` on which the exhaustive search does not finish in minutes
    (all 192 shapes and kinds tried, 8 s each: only these two went over, and the first of them
    took 236 s): head to head across two rooms of a star whose cameras see the next room's
    target, with a redundant tracker. Its maximal cliques of copies explode (issue [scale]'s
    reason); "the same answers" is asked where the old search finishes."""
    return (
        kind == "head_head"
        and shape.rooms == 2
        and shape.layout == "star"
        and shape.shared_targets
        and shape.features > 0
        and shape.redundant > 0
    )


@settings(max_examples=25, deadline=None)
@given(shape=buildings, kind=st.sampled_from(["camera_marker", "head_head", "calibration"]))
def test_buildings_plan_no_worse_than_the_exhaustive_search(templates, shape, kind):
    assume(not too_big_for_the_old_search(shape, kind))
    assert_no_worse(build(shape), templates, building_query(shape, kind))


def test_a_room_with_redundant_trackers_fuses_the_best_three_not_all(templates):
    """Without a redundant tracker the search finds the exhaustive one's derivation. With them
    it is cheaper: the old search built chains towards the query target only, so it fused the
    trackers' ways head -> room, each inverted link by link, where the fusion of the ways room
    -> head inverted once has fewer inversions; and from four trackers on the old search fused
    every tracker (its copy sets were maximal), while each fused estimate adds a sensor to the
    cost: the best three fused cost less, as many as the room has."""
    query = Query(camera(0), marker(0), "6D")

    def fused(solution) -> list[int]:
        return [len(dict(s.inputs)["AB"]) for s in solution.steps if s.template.service == "fusion"]

    def inversions(solution) -> int:
        return sum(s.template.pattern == "Inversion" for s in solution.steps)

    best = {}
    for redundant in (0, 1, 2, 3, 5):
        srg = build(Building(redundant=redundant))
        new = best[redundant] = plan(srg, templates, query)[0]
        if redundant > 3:
            continue
        old = exhaustive_planner.plan(srg, templates, query)[0]
        if redundant == 0:
            assert new.cost == pytest.approx(old.cost, rel=TOLERANCE)
            assert sorted(s.template.pattern for s in new.steps) == sorted(
                s.template.pattern for s in old.steps
            )
            continue
        assert new.cost < old.cost and inversions(new) < inversions(old)
        assert fused(old) == ([redundant + 1] if redundant <= 2 else [4])
    assert fused(best[1]) == [2]
    assert fused(best[2]) == fused(best[3]) == fused(best[5]) == [3]
    assert best[3].cost == pytest.approx(best[2].cost) == pytest.approx(best[5].cost)


# a 3D edge joins the query frames, so they are one hop apart, but no pose is derived from it:
# the ways a chain may take are counted from the shortest chain of poses (planner._span)
POINT_BETWEEN_THE_QUERY_FRAMES = [
    (0, 3, "6D", False),
    (0, 4, "3D", False),
    (1, 2, "6D", False),
    (1, 4, "6D", False),
    (2, 3, "6D", False),
]


@settings(max_examples=60, deadline=None)
@given(edges=srg_strategies.edges, query=srg_strategies.queries)
@example(
    edges=[*POINT_BETWEEN_THE_QUERY_FRAMES, (0, 2, "3D", False)],
    query=(0, 4, False),
)
@example(
    edges=[*POINT_BETWEEN_THE_QUERY_FRAMES, (0, 2, "6D", False)],
    query=(0, 4, False),
)
def test_random_srgs_plan_no_worse_than_the_exhaustive_search(templates, edges, query):
    """Random multigraphs (parallel, opposite, static and dynamic edges) with the bound on the
    alternatives kept per relation raised to 16: which alternatives a bound of 8 keeps depends
    on the order they come in, and the two searches take them in different orders (one such
    graph in 300 planned 0.83 against 0.79 with 8, the same with 16). With 64 a dense example
    takes either search half a minute.

    Within 2 % and 0.05 (a fusion step and its latency at each of two cut frames, where the
    parts fuse each side apart: :mod:`ubitrack_agent.graph.segments`): the bound still decides
    in dense graphs (five parallel estimates of one relation chained on two ways: 1.2967
    against 1.2924 with 16, the same with 32), and a group of more than ``EXACT_COPIES``
    occurrences gets greedy sets of copies, not every maximal clique. Drawn at random from this
    distribution, 426 of 426 graphs planned at no higher cost (both searches on 600 seeded
    draws, 426 within the time limit); hypothesis, searching for a counterexample, finds such
    graphs."""
    srg = new_srg()
    for a, b, edge_type, static in edges:
        add_measured_edge(srg, f"N{a}", f"N{b}", edge_type, static=static)
    if f"N{query[0]}" not in srg or f"N{query[1]}" not in srg:
        return
    q = Query(f"N{query[0]}", f"N{query[1]}", "6D", query[2])
    assert_no_worse(srg, templates, q, tolerance=0.02, allowance=0.05, per_relation=16)


def test_three_chains_a_greedy_set_of_copies_missed_are_fused_as_by_the_exhaustive_search(
    templates,
):
    """Found by the random search: three chains N0->N2 fused; a greedy set of copies missed
    them, every maximal clique of a small group does not (``matcher.EXACT_COPIES``)."""
    srg = new_srg()
    edges = [(0, 1, True), (0, 3), (0, 3, True), (1, 2), (2, 3), (2, 4), (3, 2), (2, 1)]
    for a, b, *static in edges:
        add_measured_edge(srg, f"N{a}", f"N{b}", "6D", static=bool(static))
    assert_no_worse(srg, templates, Query("N0", "N4", "6D"), per_relation=16)


def test_parallel_chains_through_a_cut_frame_cost_at_most_a_fusion_step_more(templates):
    """Found by the random search: two parallel chains through the cut frames N3 and N2. The
    old search fused them as wholes; the parts fuse each side apart (``graph/segments.py``):
    no higher variance, one more step."""
    srg = new_srg()
    for a, b in [(0, 3), (0, 3), (2, 1), (3, 2), (3, 2)]:
        add_measured_edge(srg, f"N{a}", f"N{b}", "6D", static=False)
    query = Query("N1", "N0", "6D")
    old = exhaustive_planner.plan(srg, templates, query, per_relation=16)[0]
    new = plan(srg, templates, query, per_relation=16)[0]
    assert new.edge.quality.variance <= old.edge.quality.variance * (1 + TOLERANCE)
    assert old.cost < new.cost <= old.cost + STEP_WEIGHT + 1e-9
    assert len(new.steps) == len(old.steps) + 1


@pytest.mark.parametrize("seed", range(3))
def test_the_choice_does_not_depend_on_the_order_of_announcement(templates, seed):
    srg = build(Building(rooms=2, bodies=2, redundant=1, features=4))
    shuffled = new_srg()
    edges = list(srg.edges(keys=True, data=True))
    random.Random(seed).shuffle(edges)
    for u, v, key, data in edges:
        add_measured_edge(
            shuffled,
            u,
            v,
            data["type"],
            static=data["static"],
            provider=data["provider"],
            quality=data["quality"],
            edge_id=key,
        )
    assert nx.utils.edges_equal(srg.edges(keys=True), shuffled.edges(keys=True))
    for query in (Query(camera(0), marker(1), "6D"), Query(body(0), body(1, 2), "6D")):
        first = [s.as_json() for s in plan(srg, templates, query)]
        again = [s.as_json() for s in plan(shuffled, templates, query)]
        assert first == again


def test_parts_are_shared_across_queries_and_planned_again_when_their_edges_change(templates):
    srg = build(Building(rooms=3, bodies=2, redundant=2))
    queries = [Query(body(0), body(2), "6D"), Query(body(1), body(2, 2), "6D")]
    cache = PartCache()
    for query in queries:
        cached = [s.as_json() for s in plan(srg, templates, query, cache=cache)]
        assert cached == [s.as_json() for s in plan(srg, templates, query)]
    assert cache.hits > 0  # the room of H2_1 and H2_2 was planned for the first query only
    misses = cache.misses
    without = remove_provider(srg, tracker(0))
    cached = [s.as_json() for s in plan(without, templates, queries[0], cache=cache)]
    assert cached == [s.as_json() for s in plan(without, templates, queries[0])]
    assert cache.misses == misses + 1  # room 0 changed (two trackers left); the rest did not


def test_a_room_equipped_as_another_takes_its_derivations_renamed_either_way_round(templates):
    """The derivations saturated for one room's part, renamed for a room equipped alike, are
    record for record (ids, signatures, sources, steps) those a saturation of that room's part
    gives, the query running into the room or out of it."""
    srg = build(Building(rooms=2, bodies=3, redundant=1))

    def part(r: int) -> set[str]:
        return {room(r), tracker(r), tracker(r, 1), body(r, 1), body(r, 2), body(r, 3)}

    def saturated(frames: set[str], ends: tuple[str, str]) -> tuple[dict, PartNames]:
        _, names = _part_shape(srg, templates, frames, ends, DEFAULT_SLACK, DEFAULT_PER_RELATION)
        ws = saturate(srg, templates, frames, "6D", (), goal=ends, prefix=names.prefix)
        found = {way: solutions(ws, Query(*way, "6D")) for way in (ends, ends[::-1])}
        return found, names

    def records(found: list) -> list:
        return [(s.edge, s.steps, sorted(s.records.items())) for s in found]

    planned, planned_names = saturated(part(0), (body(0), room(0)))
    fresh, names = saturated(part(1), (room(1), body(1)))
    assert planned_names != names
    for a, b in ((room(1), body(1)), (body(1), room(1))):
        was = (a.replace("1", "0", 1), b.replace("1", "0", 1))
        renamed = _renamed(planned[was], srg, planned_names, names)
        assert renamed and records(renamed) == records(fresh[(a, b)])


def test_the_part_cache_keeps_the_most_recently_used_parts():
    cache = PartCache(size=2)
    for key in ("a", "b", "c"):
        cache.put((key,), [])
    assert cache.get(("a",)) is None
    assert cache.get(("b",)) == [] and cache.get(("c",)) == []
    cache.put(("d",), [])
    assert cache.get(("b",)) is None  # b was used before c
    assert (cache.hits, cache.misses) == (2, 2)


def test_a_catalogue_without_a_chain_plans_the_region_whole(templates):
    srg = build(Building(rooms=2))
    without = [t for t in templates if t.signature != "chain"]
    with pytest.raises(NoSolutionError, match="no combination of patterns"):
        plan(srg, without, Query(body(0), body(1), "6D"))
