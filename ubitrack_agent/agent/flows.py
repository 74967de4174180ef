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

from ubitrack_agent.agent.spares import DEFAULT_REDUNDANCY, Redundancy, spare_solutions
from ubitrack_agent.graph.dataflow import DataFlow, from_solution, merge, relation_name
from ubitrack_agent.graph.frame_names import frame_hint
from ubitrack_agent.graph.planner import (
    PlanningError,
    Query,
    Solution,
    introducible_frames,
    plan,
)
from ubitrack_agent.graph.srg import remove_static_relation, static_relation_edges
from ubitrack_agent.graph.templates import Template
from ubitrack_agent.net.keys import RelationId

HYSTERESIS = 0.10
"""Relative cost margin within which running components are preferred."""

Planner = Callable[[nx.MultiDiGraph, Sequence[Template], Query], list[Solution]]
"""``graph.planner.plan``, or a memo of it (``agent.plan_memo``)."""


@dataclass(frozen=True)
class Plan:
    """The merged data flow serving every plannable relation (by :func:`plan_name`, e.g.
    ``"C->A:6D"``), the relations that cannot be planned with the reason, the components of
    each planned relation's derivation (``serving``) and those with its spares' and replicas'
    (``kept``: what :func:`stable_choice` keeps)."""

    flow: DataFlow
    relations: dict[str, RelationId] = field(default_factory=dict)
    unsolved: dict[str, str] = field(default_factory=dict)
    serving: dict[str, frozenset[str]] = field(default_factory=dict)
    kept: dict[str, frozenset[str]] = field(default_factory=dict)


Chooser = Callable[[Query, Sequence[Solution]], Solution]


def stable_choice(
    running: Set[str],
    kept: Mapping[str, Set[str]] | None = None,
    name: Callable[[Query], str] = relation_name,
) -> Chooser:
    """A ``dataflow.plan_flows`` chooser (module docstring): the cheapest solution, unless
    the relation's current flows (``kept``: its derivation's, spares' and replicas'
    components, by the relation's plan name: ``name``) have running components; then the one
    with the fewest new components within the cost margin, then the cheapest. A spare that
    runs is thus taken as it is when the derivation it stands in for loses its sensor.
    ``kept=None`` (no plan yet) counts every running component for every relation."""

    def choose(query: Query, solutions: Sequence[Solution]) -> Solution:
        mine = running if kept is None else running & kept.get(name(query), frozenset())
        if not mine:
            return solutions[0]

        def new_components(solution: Solution) -> int:
            return len(set(from_solution(solution, query).components) - mine)

        return min(within_margin(solutions), key=lambda s: (new_components(s), s.cost))

    return choose


def within_margin(solutions: Sequence[Solution]) -> list[Solution]:
    """The solutions (best first) whose cost is within :data:`HYSTERESIS` of the best: those
    :func:`stable_choice` chooses among (the best alone if costs are not numbers)."""
    limit = solutions[0].cost * (1 + HYSTERESIS) + 1e-12
    return [s for s in solutions if s.cost <= limit] or list(solutions[:1])


@dataclass(frozen=True)
class RelationPlan:
    """One relation's part of a :class:`Plan`: its data flow (empty if unsolved, then
    ``unsolved`` says why; with its spare derivations and replicas, ``agent.spares``), the
    components of its derivation (``serving``) and of its whole flow (``kept``), and the
    measured edges that derivation and its spares read
    (``edges``: an event removing one of them replans it, ``agent.replanning``). ``name`` is
    its :func:`plan_name`; ``relations`` maps the names it is planned under to the relation
    (none for a type the planner does not know).
    ``candidates`` are the components of every derivation within the cost margin
    (:func:`within_margin`): the only ones whose running can change the choice, so a worker
    that appears replans the relation only if it is one of them (``agent.replanning``)."""

    relation: RelationId
    name: str
    flow: DataFlow = field(default_factory=DataFlow)
    unsolved: str | None = None
    serving: frozenset[str] = frozenset()
    kept: frozenset[str] = frozenset()
    edges: frozenset[str] = frozenset()
    relations: Mapping[str, RelationId] = field(default_factory=dict)
    candidates: frozenset[str] = frozenset()


def plan_relation(
    srg: nx.MultiDiGraph,
    templates: Sequence[Template],
    relation: RelationId,
    running: Set[str] = frozenset(),
    kept: Mapping[str, Set[str]] | None = None,
    planner: Planner = plan,
    redundancy: Redundancy = DEFAULT_REDUNDANCY,
) -> RelationPlan:
    """A derivation of ``relation`` chosen by :func:`stable_choice` (``kept``: the
    components of the previous plan's flows, by plan name; ``None`` before the first plan)
    among those ``planner`` finds. A recalibration is planned on ``srg`` without the
    measured static edges of its relation (``srg.remove_static_relation``), so it is computed
    from the other edges; its unsolved reason says which edges it ignored. The chosen
    derivation's spares and replicas (``agent.spares``), as ``redundancy`` asks, are in its
    flow. O(one ``planner`` call + the data flows of the derivations within
    the cost margin, of the spares and of the replicas)."""
    try:
        query = Query(relation.source, relation.target, relation.type, relation.static)
    except PlanningError as exc:
        return RelationPlan(relation, str(relation), unsolved=str(exc))
    name = plan_name(relation)
    ignored: list[str] = []
    if relation.recalibrate:
        ignored = static_relation_edges(srg, relation.source, relation.target)
        srg = remove_static_relation(srg, relation.source, relation.target)
        choose = stable_choice(running, kept, _recalibration_name)
    else:
        choose = stable_choice(running, kept)
    names = {name: relation}
    try:
        new = introducible_frames(srg, templates, query)  # a calibration may add a frame
        missing = [f for f in (relation.source, relation.target) if f not in srg and f not in new]
        if missing:
            raise PlanningError(f"no provider announces frame(s) {', '.join(missing)}")
        solutions = planner(srg, templates, query)
    except PlanningError as exc:
        without = f"without the measured static edge(s) {', '.join(ignored)}: " if ignored else ""
        hint = frame_hint(relation.source, relation.target, srg.nodes)  # a frame not announced
        reason = without + str(exc) + (f"; {hint}" if hint else "")
        return RelationPlan(relation, name, unsolved=reason, relations=names)
    solution = choose(query, solutions)
    spares = spare_solutions(solution, solutions) if redundancy.spares else []
    flow, own = from_solution(solution, query), relation_name(query)
    others = [from_solution(spare, query) for spare in spares]
    if flow.components:  # (a relation read from a measured edge has nothing to replicate)
        others += [from_solution(solution, query, k) for k in range(1, redundancy.replicas + 1)]
    merged = merge(
        [
            DataFlow(flow.components, {name: flow.relations[own]}),
            *(DataFlow(f.components, spares={name: (f.relations[own],)}) for f in others),
        ]
    )
    return RelationPlan(
        relation,
        name,
        merged,
        serving=frozenset(flow.components),
        kept=frozenset(merged.components),
        edges=frozenset(
            r.id for s in (solution, *spares) for r in s.records.values() if r.measured
        ),
        relations=names,
        candidates=frozenset().union(
            *(from_solution(s, query).components for s in within_margin(solutions))
        ),
    )


def planning_order(relation: RelationId) -> tuple[bool, str]:
    """The order in which relations' flows are merged (shared components keep the ids of the
    first flow that has them: ``dataflow.merge``): plain relations, then recalibrations."""
    return relation.recalibrate, str(relation)


def combine(parts: Iterable[RelationPlan]) -> Plan:
    """One plan of the relations' ``parts`` (taken in :func:`planning_order`), their flows
    merged. O(components of all parts)."""
    ordered = sorted(parts, key=lambda part: planning_order(part.relation))
    return Plan(
        merge(part.flow for part in ordered),
        {name: r for part in ordered for name, r in part.relations.items()},
        {part.name: part.unsolved for part in ordered if part.unsolved is not None},
        {part.name: part.serving for part in ordered if part.unsolved is None},
        {part.name: part.kept for part in ordered if part.unsolved is None},
    )


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


def plan_relations(
    srg: nx.MultiDiGraph,
    templates: Sequence[Template],
    relations: Iterable[RelationId],
    running: Set[str] = frozenset(),
    previous: Plan | None = None,
    redundancy: Redundancy = DEFAULT_REDUNDANCY,
) -> Plan:
    """A derivation of each relation (:func:`plan_relation`, :func:`stable_choice` given the
    ``previous`` plan), merged into one data flow: every relation planned again
    (``agent.replanning`` plans only those an event can affect). O(relations x one plan)."""
    kept = previous.kept if previous else None
    return combine(
        plan_relation(srg, templates, r, running, kept, plan, redundancy) for r in set(relations)
    )
