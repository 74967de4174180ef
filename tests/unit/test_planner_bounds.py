"""What the search skips before forming it (session 20, issue [scale]): a correspondence group
whose space expansions' cost floor is no cheaper than the dearest alternative of a full
relation (``Workspace.group_outclassed``), a chain whose cost is not
(``Workspace._chain_outclassed``), and a chain's last link whose ends are too far from the
query frames (``Workspace.last_link``). The floor is below every expansion's cost, and
skipping changes no answer: every solution, every step, byte for byte."""

from __future__ import annotations

import json

import pytest

from bench.building import Building, body, build, camera, marker
from ubitrack_agent.graph import matcher, planner
from ubitrack_agent.graph.planner import Query, Workspace, edge_cost, plan, propagate

HEAD_TO_HEAD = (Building(rooms=2, bodies=4, redundant=2), Query(body(0), body(1), "6D"))
IN_ROOM = (Building(redundant=7), Query(camera(0), marker(0), "6D"))


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
    far_links = []

    def counted_links(ws, template):
        at = last_link(ws, template)

        def counting_at(*args):
            fits = at(*args)

            def counting(edge):
                found = fits(edge)
                far_links.append(not found)
                return found

            return counting if fits else None

        return counting_at if at else None

    monkeypatch.setattr(Workspace, "group_outclassed", counted(group_outclassed))
    monkeypatch.setattr(Workspace, "_chain_outclassed", counted(chain_outclassed))
    monkeypatch.setattr(Workspace, "last_link", counted_links)
    pruned = answers(srg, templates, query, per_relation=per_relation)
    assert any(skipped) and any(far_links), "the setup must exercise the skips"
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
