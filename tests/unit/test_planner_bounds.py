"""What the search skips before forming it (session 20, issue [scale]): a correspondence group
whose space expansions' cost floor is no cheaper than the dearest alternative of a full
relation (``Workspace.group_outclassed``), a chain whose cost is not
(``Workspace._chain_outclassed``), and a chain's last link whose ends are too far from the
query frames (``Workspace.last_link``). The floor is below every expansion's cost, and
skipping changes no answer: every solution, every step, byte for byte. A chain's link of a
type the chain cannot take is not offered (session 22), and the ways around a chain, searched
on bit sets, are the plain breadth-first hops."""

from __future__ import annotations

import gc
import itertools
import json
import math

import networkx as nx
import pytest

from bench.building import Building, body, build, camera, marker
from ubitrack_agent.graph import matcher, planner
from ubitrack_agent.graph.planner import Query, Workspace, edge_cost, plan, propagate
from ubitrack_agent.graph.ways import hop_distances

HEAD_TO_HEAD = (Building(rooms=2, bodies=4, redundant=2), Query(body(0), body(1), "6D"))
IN_ROOM = (Building(redundant=7), Query(camera(0), marker(0), "6D"))
CORRIDOR = (Building(rooms=3, layout="corridor"), Query(camera(0), marker(2), "6D"))


def answers(srg, templates, query, **options) -> str:
    return json.dumps([s.as_json() for s in plan(srg, templates, query, **options)])


@pytest.mark.parametrize("per_relation", [2, 8])
@pytest.mark.parametrize("shape, query", [HEAD_TO_HEAD, IN_ROOM])
def test_skipping_outclassed_groups_and_chains_changes_no_answer(
    templates, monkeypatch, shape, query, per_relation
):
    srg = build(shape)
    skipped = []
    group_outclassed = Workspace.group_outclassed
    chain_outclassed = Workspace._chain_outclassed

    def counted(check):
        def wrapper(*args):
            found = check(*args)
            skipped.append(found)
            return found

        return wrapper

    last_link = Workspace.last_link
    far_links, narrowed = [], []

    def counted_links(ws, template):
        at = last_link(ws, template)

        def counting_at(*args):
            test = at(*args)
            if test is None:
                return None

            def counting(edge):
                found = test.fits(edge)
                far_links.append(not found)
                return found

            def narrowing(ids):
                kept = list(test.narrow(ids))
                left_out = [e for e in ids if e not in kept]
                # only edges the full test rejects are left out, the others kept in order
                assert not any(test.fits(ws.index.edges[e]) for e in left_out)
                assert kept == [e for e in ids if e not in left_out]
                narrowed.extend(left_out)
                return kept

            return matcher.LastTest(counting, narrowing if test.narrow else None)

        return counting_at if at else None

    monkeypatch.setattr(Workspace, "group_outclassed", counted(group_outclassed))
    monkeypatch.setattr(Workspace, "_chain_outclassed", counted(chain_outclassed))
    monkeypatch.setattr(Workspace, "last_link", counted_links)
    monkeypatch.setattr(matcher, "NARROWED_FROM", 0)  # however few the candidates
    pruned = answers(srg, templates, query, per_relation=per_relation)
    assert any(skipped) and any(far_links), "the setup must exercise the skips"
    assert narrowed or query.source != camera(0), "a room's last links must be narrowed"
    monkeypatch.setattr(Workspace, "group_outclassed", lambda *args: False)
    monkeypatch.setattr(Workspace, "_chain_outclassed", lambda *args: False)
    monkeypatch.setattr(Workspace, "last_link", lambda *args: None)
    assert answers(srg, templates, query, per_relation=per_relation) == pruned


def test_the_floor_of_a_group_is_below_every_expansion_it_yields(templates, monkeypatch):
    """Every group the search bounds: its floor is at most the cost of each of its space
    expansions (what ``Workspace.apply`` would give their outputs)."""
    shape, query = HEAD_TO_HEAD
    checked = []
    group_outclassed = Workspace.group_outclassed

    def checking(ws, key, members):
        floor = planner._space_floor(members, ws.index, ws._copy_costs)
        for instance in matcher.expand_group(members, ws.index):
            if instance.expansion != "space":
                continue
            inputs = [ws.index.edges[e] for e in instance.input_edges()]
            providers = frozenset().union(*(e.providers for e in inputs))
            steps = frozenset().union(*(e.steps for e in inputs))
            cost = edge_cost(propagate(instance, ws.index.edges), len(providers), len(steps) + 1)
            assert floor <= cost, (key, floor, cost)
            checked.append(cost - floor)
        return group_outclassed(ws, key, members)

    monkeypatch.setattr(Workspace, "group_outclassed", checking)
    plan(build(shape), templates, query)
    assert len(checked) > 50
    assert min(checked) < 0.01  # tight somewhere: the floor is reached by the cheapest set


def _room_workspace(templates) -> tuple[planner.Workspace, Query]:
    """The saturated workspace of camera -> marker in a room with seven redundant trackers."""
    shape, query = IN_ROOM
    srg = build(shape)
    frames = planner.relevant_frames(srg, query.source, query.target, planner.DEFAULT_SLACK)
    goal = (query.source, query.target)
    return planner.saturate(srg, templates, frames, query.type, goal=goal), query


def test_a_narrowing_is_remembered_per_list_and_reads_only_its_new_edges(templates):
    """``_MemoisedNarrowing``: the same list narrowed again is not read again; grown at its
    end, only the new edges are; after an edge is retired, or for another narrowing or another
    list, the whole list is."""
    ws, _ = _room_workspace(templates)
    asked = []

    def kept(ids):
        asked.append(list(ids))
        return [e for e in ids if e.endswith("+")]

    narrowing, other = (planner._MemoisedNarrowing(ws.index, kept) for _ in range(2))
    ids = ["a+", "b", "c+"]
    assert narrowing(ids) == ("a+", "c+")
    assert narrowing(ids) == ("a+", "c+") and len(asked) == 1
    ids.append("d+")
    assert narrowing(ids) == ("a+", "c+", "d+") and asked[-1] == ["d+"]
    assert other(ids) == ("a+", "c+", "d+") and asked[-1] == ids
    assert narrowing(list(ids)) == ("a+", "c+", "d+") and asked[-1] == ids
    ids.remove("a+")
    ws.index.retired.add("a+")  # as EdgeIndex.retire does
    ids.append("e")  # as long as before
    assert narrowing(ids) == ("c+", "d+") and asked[-1] == ids


def test_a_chain_from_a_frame_other_than_a_query_frame_is_offered_no_point(templates):
    """The type of a chain's unbound link is put to the test of partial occurrences before
    its candidates are listed: points are carried only into the query frames."""
    ws, query = _room_workspace(templates)
    chain = next(t for t in templates if t.signature == "chain")
    viable = ws.viable_chain(chain)
    first, second = chain.inputs
    var = second.type_var
    assert var is not None

    def kinds(start: str) -> list[str]:
        roles = {first.source: start, first.target: "R0"}
        return matcher._viable_kinds(chain, var, roles, {}, {0: "any"}, viable)

    assert kinds(query.source) == list(chain.type_vars[var])
    assert "3D" in chain.type_vars[var] and "3D" not in kinds("T0_1")


def test_the_ways_around_a_chain_are_the_breadth_first_hops(templates):
    """``Workspace._avoiding`` (shortest-way counts, else breadth-first on bit sets) gives the
    hops ``ways.hop_distances`` gives over the frames' names, for every start and goal of the
    region and sets of frames to avoid (none, one, two neighbours in the frames' order, every
    third)."""
    ws, _ = _room_workspace(templates)
    frames = sorted(ws.neighbours)
    assert len(frames) > 10
    compared = 0
    pairs = list(itertools.pairwise(frames))
    for k, avoided in enumerate([(), *((f,) for f in frames), *pairs, tuple(frames[::3])]):
        avoid = 0
        for frame in avoided:
            avoid |= ws._bits[frame]
        for start in frames[k % 3 :: 3]:
            expected = hop_distances(ws._around, (start,), avoid=frozenset(avoided))
            for goal in frames:
                if start in avoided or goal in avoided:
                    continue
                assert ws._avoiding(start, goal, avoid) == expected.get(goal, math.inf)
                compared += 1
    assert compared > 500


def test_ways_between_frames_and_their_hops_are_those_of_a_breadth_first_search(templates):
    """``Workspace._ways_to`` (one hop: adjacent; two: common neighbours; further: a counting
    search) gives the number of shortest ways networkx counts between every two frames of the
    region, and ``Workspace._distance`` (bit sets, stopping at the goal) their hops."""
    ws, _ = _room_workspace(templates)
    graph = nx.Graph([(a, b) for a, near in ws.neighbours.items() for b in near])
    frames = sorted(graph)
    hops_seen = set()
    for goal in frames:
        hops = hop_distances(ws._around, (goal,))
        for frame in frames:
            assert ws._distance(frame, goal) == hops[frame]
            if frame == goal:
                continue
            ways = sum(1 for _ in nx.all_shortest_paths(graph, frame, goal))
            at = ws._bits[frame].bit_length() - 1
            assert ws._ways_to(goal, at, hops[frame]) == ways
            hops_seen.add(hops[frame])
    assert {1, 2, 3} <= hops_seen, "every way of counting must be exercised"


@pytest.mark.parametrize("shape, query", [HEAD_TO_HEAD, IN_ROOM, CORRIDOR])
def test_a_plan_leaves_nothing_to_the_cyclic_collector(templates, shape, query):
    """A plan's objects form no reference cycle, so reference counting frees all of them when
    it returns: what ``plan`` relies on to pause the collector (``core.heap``). Before, the
    workspace was in cycles (its narrowings held it, recursive closures held themselves), and
    6,566 objects of a plan in the room were left to the collector."""
    srg = build(shape)
    plan(srg, templates, query)  # networkx compiles its decorators at their first call
    was_on = gc.isenabled()
    gc.disable()
    try:
        gc.collect()
        found = plan(srg, templates, query)
        assert found
        del found
        assert gc.collect() == 0
    finally:
        if was_on:
            gc.enable()
