"""Plan every queried relation on the live SRG and merge the flows (sharing, section 5.1).

Stability: among the solutions whose cost is within :data:`HYSTERESIS` of the best, the agent
takes the one that needs the fewest components not already running. A marginally cheaper
derivation is not worth stopping a working flow and starting another (on the paper's setup,
losing the A.R.T. tracker leaves a camera-only derivation through the running pose estimation
at 4 % above a fresh one that needs six new components).

A recalibration (``RelationId.recalibrate``) is planned on its own SRG, the live one without
the measured static edges between its frames (``graph.srg.remove_static_relation``), under its
own name (:func:`plan_name`); every other relation on the live SRG, so the stored
edge keeps serving them while the recalibration runs.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence, Set
from dataclasses import dataclass, field

import networkx as nx

from ubitrack_agent.graph.dataflow import (
    DataFlow,
    from_solution,
    merge,
    plan_flows,
    relation_name,
)
from ubitrack_agent.graph.planner import PlanningError, Query, Solution, introducible_frames
from ubitrack_agent.graph.srg import remove_static_relation, static_relation_edges
from ubitrack_agent.graph.templates import Template
from ubitrack_agent.net.keys import RelationId

HYSTERESIS = 0.10
"""Relative cost margin within which running components are preferred."""


@dataclass(frozen=True)
class Plan:
    """The merged data flow serving every plannable relation (by :func:`plan_name`, e.g.
    ``"C->A:6D"``), and the relations that cannot be planned with the reason."""

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


def _plan_on(
    srg: nx.MultiDiGraph,
    templates: Sequence[Template],
    relations: Iterable[RelationId],
    choose: Callable[[Query, Sequence[Solution]], Solution],
) -> Plan:
    """A derivation of each relation on ``srg`` chosen by ``choose``, merged into one data flow
    under the data flow's relation names (``"C->HT:6D/static"``)."""
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
    flow, unresolved = plan_flows(srg, templates, queries, choose)
    return Plan(flow, names, {**unsolved, **unresolved})


def plan_name(relation: RelationId) -> str:
    """The name a plan (and the agent's status) gives ``relation``: the data flow's relation
    name (``"C->A:6D"``, ``"C->HT:6D/static"``), or for a recalibration
    ``"C->HT:6D/recalibrate"``, apart from the static relation other queries may be using
    meanwhile. ``PlanningError`` for a type the planner does not know."""
    name = relation_name(Query(relation.source, relation.target, relation.type, relation.static))
    return name.replace("/static", "/recalibrate") if relation.recalibrate else name


def _recalibration_plan(
    srg: nx.MultiDiGraph,
    templates: Sequence[Template],
    relation: RelationId,
    choose: Callable[[Query, Sequence[Solution]], Solution],
) -> Plan:
    """The static ``relation`` planned on ``srg`` without the measured static edges between
    its frames (``srg.remove_static_relation``), so it is computed from the other edges
    (calibrated over time); an unsolved reason says which edges it ignored."""
    source, target = relation.source, relation.target
    ignored = static_relation_edges(srg, source, target)
    planned = _plan_on(remove_static_relation(srg, source, target), templates, [relation], choose)
    if not planned.relations:
        return planned  # not a query the planner takes (its type), with the reason
    name = plan_name(relation)
    without = f"without the measured static edge(s) {', '.join(ignored)}: " if ignored else ""
    binding = next(iter(planned.flow.relations.values()), None)
    reason = next(iter(planned.unsolved.values()), None)
    return Plan(
        DataFlow(planned.flow.components, {name: binding} if binding else {}),
        {name: relation},
        {name: without + reason} if reason else {},
    )


def plan_relations(
    srg: nx.MultiDiGraph,
    templates: Sequence[Template],
    relations: Iterable[RelationId],
    running: Set[str] = frozenset(),
) -> Plan:
    """A derivation of each relation (:func:`stable_choice`), merged into one data flow. A
    recalibration is planned on the SRG without the measured static edges of its relation,
    every other relation on the whole SRG (so the stored edge keeps serving them)."""
    choose = stable_choice(running)
    relations = set(relations)
    plans = [_plan_on(srg, templates, [r for r in relations if not r.recalibrate], choose)]
    plans += [
        _recalibration_plan(srg, templates, relation, choose)
        for relation in sorted((r for r in relations if r.recalibrate), key=str)
    ]
    return Plan(
        merge(plan.flow for plan in plans),
        {name: r for plan in plans for name, r in plan.relations.items()},
        {name: reason for plan in plans for name, reason in plan.unsolved.items()},
    )
