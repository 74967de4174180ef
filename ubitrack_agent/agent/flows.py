"""Plan every queried relation on the live SRG and merge the flows (sharing, section 5.1).

Stability: for a relation the agent serves already, among the solutions whose cost is within
:data:`HYSTERESIS` of the best, the agent takes the one that needs the fewest components beside
the running ones of the relation's current derivation. A marginally cheaper derivation is not
worth stopping a working flow and starting another (on the paper's setup without the A.R.T.
tracker, 2D-3D pose estimation of C->A on the marker balls expressed in A costs 1.5 % more
than pose estimation of C->WT followed by WT->A: whichever runs stays). A new relation gets
the cheapest derivation, even where components running for another relation would make a
worse one cheap to start (after a live C->HT calibration, its inversion and concatenations
would otherwise pull a new C->A query onto the A.R.T.-only path, within the margin of
fusion). Before the agent's first plan (a restarted agent adopting running workers) every
running component counts.

A recalibration (``RelationId.recalibrate``) is planned on its own SRG, the live one without
the measured static edges between its frames (``graph.srg.remove_static_relation``), under its
own name (:func:`plan_name`); every other relation on the live SRG, so the stored edge keeps
serving them while the recalibration runs.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence, Set
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
    ``"C->A:6D"``), the relations that cannot be planned with the reason, and the components
    of each planned relation's derivation (what :func:`stable_choice` keeps)."""

    flow: DataFlow
    relations: dict[str, RelationId] = field(default_factory=dict)
    unsolved: dict[str, str] = field(default_factory=dict)
    serving: dict[str, frozenset[str]] = field(default_factory=dict)


Chooser = Callable[[Query, Sequence[Solution]], Solution]


def stable_choice(
    running: Set[str],
    serving: Mapping[str, Set[str]] | None = None,
    name: Callable[[Query], str] = relation_name,
) -> Chooser:
    """A ``dataflow.plan_flows`` chooser (module docstring): the cheapest solution, unless
    the relation's current derivation (``serving``, by the relation's plan name: ``name``) has
    running components; then the one with the fewest new components within the cost margin,
    then the cheapest. ``serving=None`` (no plan yet) counts every running component for
    every relation."""

    def choose(query: Query, solutions: Sequence[Solution]) -> Solution:
        kept = running if serving is None else running & serving.get(name(query), frozenset())
        if not kept:
            return solutions[0]
        limit = solutions[0].cost * (1 + HYSTERESIS) + 1e-12

        def new_components(solution: Solution) -> int:
            return len(set(from_solution(solution, query).components) - kept)

        eligible = [s for s in solutions if s.cost <= limit] or solutions[:1]  # NaN-proof
        return min(eligible, key=lambda s: (new_components(s), s.cost))

    return choose


def _plan_on(
    srg: nx.MultiDiGraph,
    templates: Sequence[Template],
    relations: Iterable[RelationId],
    choose: Chooser,
    plan_name_of: Callable[[Query], str] = relation_name,
) -> Plan:
    """A derivation of each relation on ``srg`` chosen by ``choose``, merged into one data flow
    under the data flow's relation names (``"C->HT:6D/static"``), with the components of each
    derivation by ``plan_name_of``."""
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
    serving: dict[str, frozenset[str]] = {}

    def choose_and_remember(query: Query, solutions: Sequence[Solution]) -> Solution:
        chosen = choose(query, solutions)
        serving[plan_name_of(query)] = frozenset(from_solution(chosen, query).components)
        return chosen

    flow, unresolved = plan_flows(srg, templates, queries, choose_and_remember)
    return Plan(flow, names, {**unsolved, **unresolved}, serving)


def plan_name(relation: RelationId) -> str:
    """The name a plan (and the agent's status) gives ``relation``: the data flow's relation
    name (``"C->A:6D"``, ``"C->HT:6D/static"``), or for a recalibration
    ``"C->HT:6D/recalibrate"``, apart from the static relation other queries may be using
    meanwhile; for a type the planner does not know, ``str(relation)`` (under which the plan
    says why it is unsolved)."""
    try:
        query = Query(relation.source, relation.target, relation.type, relation.static)
    except PlanningError:
        return str(relation)
    name = relation_name(query)
    return _recalibration_name(name) if relation.recalibrate else name


def _recalibration_name(query: Query | str) -> str:
    """The plan name of a recalibration of the static ``query`` (or of its relation name)."""
    name = query if isinstance(query, str) else relation_name(query)
    return name.replace("/static", "/recalibrate")


def _recalibration_plan(
    srg: nx.MultiDiGraph,
    templates: Sequence[Template],
    relation: RelationId,
    choose: Chooser,
) -> Plan:
    """The static ``relation`` planned on ``srg`` without the measured static edges between
    its frames (``srg.remove_static_relation``), so it is computed from the other edges
    (calibrated over time); an unsolved reason says which edges it ignored."""
    source, target = relation.source, relation.target
    ignored = static_relation_edges(srg, source, target)
    without_stored = remove_static_relation(srg, source, target)
    planned = _plan_on(without_stored, templates, [relation], choose, _recalibration_name)
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
        planned.serving,
    )


def plan_relations(
    srg: nx.MultiDiGraph,
    templates: Sequence[Template],
    relations: Iterable[RelationId],
    running: Set[str] = frozenset(),
    previous: Plan | None = None,
) -> Plan:
    """A derivation of each relation (:func:`stable_choice` given the ``previous`` plan),
    merged into one data flow. A recalibration is planned on the SRG without the measured
    static edges of its relation, every other relation on the whole SRG (so the stored edge
    keeps serving them)."""
    serving = previous.serving if previous else None
    relations = set(relations)
    plain = [r for r in relations if not r.recalibrate]
    plans = [_plan_on(srg, templates, plain, stable_choice(running, serving))]
    recalibrating = stable_choice(running, serving, _recalibration_name)
    plans += [
        _recalibration_plan(srg, templates, relation, recalibrating)
        for relation in sorted((r for r in relations if r.recalibrate), key=str)
    ]
    return Plan(
        merge(plan.flow for plan in plans),
        {name: r for plan in plans for name, r in plan.relations.items()},
        {name: reason for plan in plans for name, reason in plan.unsolved.items()},
        {name: parts for plan in plans for name, parts in plan.serving.items()},
    )
