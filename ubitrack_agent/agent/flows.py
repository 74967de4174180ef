"""Plan every queried relation on the live SRG and merge the flows (sharing, section 5.1).

Stability: among the solutions whose cost is within :data:`HYSTERESIS` of the best, the agent
takes the one that needs the fewest components not already running. A marginally cheaper
derivation is not worth stopping a working flow and starting another (on the paper's setup,
losing the A.R.T. tracker leaves a camera-only derivation through the running pose estimation
at 4 % above a fresh one that needs six new components).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence, Set
from dataclasses import dataclass, field

import networkx as nx

from ..dataflow import DataFlow, from_solution, merge, relation_name
from ..keys import RelationId
from ..planner import PlanningError, Query, plan
from ..templates import Template

HYSTERESIS = 0.10
"""Relative cost margin within which running components are preferred."""


@dataclass(frozen=True)
class Plan:
    """The merged data flow serving every plannable relation (by the data flow's relation
    names, e.g. ``"C->A:6D"``), and the relations that cannot be planned with the reason."""

    flow: DataFlow
    relations: dict[str, RelationId] = field(default_factory=dict)
    unsolved: dict[str, str] = field(default_factory=dict)


def _stable_choice(flows: list[tuple[float, DataFlow]], running: Set[str]) -> DataFlow:
    """The flow to run: the cheapest, unless components are running; then the one with the
    fewest new components within the cost margin, then the cheapest."""
    if not running:
        return flows[0][1]
    best = flows[0][0]
    eligible = [(cost, flow) for cost, flow in flows if cost <= best * (1 + HYSTERESIS) + 1e-12]
    return min(eligible, key=lambda item: (len(set(item[1].components) - running), item[0]))[1]


def plan_relations(
    srg: nx.MultiDiGraph,
    templates: Sequence[Template],
    relations: Iterable[RelationId],
    running: Set[str] = frozenset(),
) -> Plan:
    """A derivation of each relation (``planner.plan``), merged into one data flow."""
    chosen, names, unsolved = [], {}, {}
    for relation in sorted(set(relations), key=str):
        try:
            query = Query(relation.source, relation.target, relation.type, relation.static)
        except PlanningError as exc:
            unsolved[str(relation)] = str(exc)
            continue
        name = relation_name(query)
        names[name] = relation
        missing = [f for f in (relation.source, relation.target) if f not in srg]
        if missing:
            unsolved[name] = f"no provider announces frame(s) {', '.join(missing)}"
            continue
        try:
            solutions = plan(srg, templates, query)
        except PlanningError as exc:
            unsolved[name] = str(exc)
            continue
        flows = [(solution.cost, from_solution(solution, query)) for solution in solutions]
        chosen.append(_stable_choice(flows, running))
    return Plan(merge(chosen), names, unsolved)
