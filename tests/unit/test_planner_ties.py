"""Ties between equally dear derivations are broken on what they compute (session 23, issue
[scale]: "where two derivations tie, the choice is deterministic"): the derivation's signature
(``EdgeRecord.signature``), not the order in which steps were made, so shifting every step id
changes no answer, and a full relation drops the same one of equally dear alternatives
whatever order they came in."""

from __future__ import annotations

import itertools
import json
from dataclasses import dataclass

import pytest

from bench.building import build
from bench.building_bench import head_to_head
from bench.plan_answers import random_case
from ubitrack_agent.graph import planner
from ubitrack_agent.graph.matcher import EdgeRecord
from ubitrack_agent.graph.planner import Workspace, plan
from ubitrack_agent.graph.srg import Quality

SHIFT = 96


@dataclass
class _ShiftedWorkspace(Workspace):
    """A workspace whose step ids start ``SHIFT`` further on (placeholders the planner never
    looks up): as if as many steps had been made before."""

    def __post_init__(self) -> None:
        self.steps.update((f"{self.prefix}placeholder{i}", None) for i in range(SHIFT))


def answers(srg, templates, query, **options) -> str:
    return json.dumps([s.as_json() for s in plan(srg, templates, query, **options)])


CASES = [  # cases of bench.plan_answers whose answers moved with the step ids before
    (build(head_to_head(3, 1).shape), head_to_head(3, 1).query),
    (build(head_to_head(4, 2).shape), head_to_head(4, 2).query),
    random_case(235),
    random_case(389),
]


@pytest.mark.parametrize("per_relation", [8, 16])
@pytest.mark.parametrize("case", range(len(CASES)))
def test_shifting_every_step_id_changes_no_answer(templates, monkeypatch, case, per_relation):
    srg, query = CASES[case]
    before = answers(srg, templates, query, per_relation=per_relation)
    monkeypatch.setattr(planner, "Workspace", _ShiftedWorkspace)
    assert answers(srg, templates, query, per_relation=per_relation) == before


def record(name: str, cost: float) -> EdgeRecord:
    """An inferred A->B edge of the given cost whose signature is its name."""
    return EdgeRecord(
        id=f"A->B:6D@{name}",
        source="A",
        target="B",
        type="6D",
        static=False,
        mode="push",
        measured=False,
        provider="test",
        quality=Quality(0.0, 0.0, 0.0),
        sources=frozenset({name}),
        cost=cost,
        canon=name,
        signature=("t", "none", "out", ((("", name),),), ()),
    )


def admitted(ws: Workspace, r: EdgeRecord) -> None:
    """``r`` put to the "new or better edge" rule as ``Workspace.apply`` puts it."""
    if not ws._outclassed(("A", "B", "6D", False), r.cost, r.sources) and ws._admit(r):
        ws.index.add(r)
        ws.by_relation[("A", "B", "6D", False)].append(r.id)


def test_a_full_relation_drops_the_greater_signature_of_equally_dear_ones_in_any_order():
    for order in itertools.permutations([record("b", 2.0), record("c", 2.0), record("d", 2.0)]):
        ws = Workspace(per_relation=3)
        for r in order:
            admitted(ws, r)
        admitted(ws, record("a", 1.0))
        kept = sorted(ws.by_relation[("A", "B", "6D", False)])
        assert kept == ["A->B:6D@a", "A->B:6D@b", "A->B:6D@c"]
        assert ws.index.retired == {"A->B:6D@d"}


def test_a_rebracketing_as_dear_as_a_kept_one_takes_its_slot_only_if_it_comes_first():
    first, second = record("x", 2.0), record("y", 2.0)
    second = EdgeRecord(**{**second.__dict__, "canon": first.canon})  # one computation
    for order in ((first, second), (second, first)):
        ws = Workspace()
        for r in order:
            admitted(ws, r)
        assert ws.by_relation[("A", "B", "6D", False)] == [first.id]
