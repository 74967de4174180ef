"""Plan every queried relation on the live SRG and merge the flows (sharing, section 5.1).

Stability: among the solutions whose cost is within :data:`HYSTERESIS` of the best, the agent
takes the one that needs the fewest components not already running. A marginally cheaper
derivation is not worth stopping a working flow and starting another (on the paper's setup,
losing the A.R.T. tracker leaves a camera-only derivation through the running pose estimation
at 4 % above a fresh one that needs six new components).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence, Set
from dataclasses import dataclass, field

import networkx as nx

from ubitrack_agent.graph.dataflow import DataFlow, from_solution, plan_flows, relation_name
from ubitrack_agent.graph.planner import PlanningError, Query, Solution, introducible_frames
from ubitrack_agent.graph.templates import Template
from ubitrack_agent.net.keys import RelationId

HYSTERESIS = 0.10
"""Relative cost margin within which running components are preferred."""


@dataclass(frozen=True)
class Plan:
    """The merged data flow serving every plannable relation (by the data flow's relation
    names, e.g. ``"C->A:6D"``), and the relations that cannot be planned with the reason."""

    flow: DataFlow
    relations: dict[str, RelationId] = field(default_factory=dict)
    unsolved: dict[str, str] = field(default_factory=dict)


def stable_choice(running: Set[str]) -> Callable[[Query, Sequence[Solution]], Solution]:
    """A ``dataflow.plan_flows`` chooser: the cheapest solution, unless components are
    running; then the one with the fewest new components within the cost margin, then the
    cheapest."""

    def choose(query: Query, solutions: Sequence[Solution]) -> Solution:
        if not running:
            return solutions[0]
        limit = solutions[0].cost * (1 + HYSTERESIS) + 1e-12

        def new_components(solution: Solution) -> int:
            return len(set(from_solution(solution, query).components) - running)

        eligible = [s for s in solutions if s.cost <= limit]
        return min(eligible, key=lambda s: (new_components(s), s.cost))

    return choose


def plan_relations(
    srg: nx.MultiDiGraph,
    templates: Sequence[Template],
    relations: Iterable[RelationId],
    running: Set[str] = frozenset(),
) -> Plan:
    """A derivation of each relation (:func:`stable_choice`), merged into one data flow."""
    queries, names, unsolved = [], {}, {}
    for relation in sorted(set(relations), key=str):
        try:
            query = Query(relation.source, relation.target, relation.type, relation.static)
        except PlanningError as exc:
            unsolved[str(relation)] = str(exc)
            continue
        name = relation_name(query)
        names[name] = relation
        new = introducible_frames(srg, templates, query)  # a calibration may add a frame
        missing = [f for f in (relation.source, relation.target) if f not in srg and f not in new]
        if missing:
            unsolved[name] = f"no provider announces frame(s) {', '.join(missing)}"
            continue
        queries.append(query)
    flow, unresolved = plan_flows(srg, templates, queries, stable_choice(running))
    return Plan(flow, names, {**unsolved, **unresolved})
