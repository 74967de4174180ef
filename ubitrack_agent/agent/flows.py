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
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence, Set
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
    names, e.g. ``"C->A:6D"``), the relations that cannot be planned with the reason, and the
    components of each planned relation's derivation (what :func:`stable_choice` keeps)."""

    flow: DataFlow
    relations: dict[str, RelationId] = field(default_factory=dict)
    unsolved: dict[str, str] = field(default_factory=dict)
    serving: dict[str, frozenset[str]] = field(default_factory=dict)


def stable_choice(
    running: Set[str], serving: Mapping[str, Set[str]] | None = None
) -> Callable[[Query, Sequence[Solution]], Solution]:
    """A ``dataflow.plan_flows`` chooser (module docstring): the cheapest solution, unless
    the relation's current derivation (``serving``, by relation name) has running components;
    then the one with the fewest new components within the cost margin, then the cheapest.
    ``serving=None`` (no plan yet) counts every running component for every relation."""

    def choose(query: Query, solutions: Sequence[Solution]) -> Solution:
        kept = (
            running if serving is None else running & serving.get(relation_name(query), frozenset())
        )
        if not kept:
            return solutions[0]
        limit = solutions[0].cost * (1 + HYSTERESIS) + 1e-12

        def new_components(solution: Solution) -> int:
            return len(set(from_solution(solution, query).components) - kept)

        eligible = [s for s in solutions if s.cost <= limit]
        return min(eligible, key=lambda s: (new_components(s), s.cost))

    return choose


def plan_relations(
    srg: nx.MultiDiGraph,
    templates: Sequence[Template],
    relations: Iterable[RelationId],
    running: Set[str] = frozenset(),
    previous: Plan | None = None,
) -> Plan:
    """A derivation of each relation (:func:`stable_choice` given the ``previous`` plan),
    merged into one data flow."""
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
    choose = stable_choice(running, previous.serving if previous else None)
    serving: dict[str, frozenset[str]] = {}

    def choose_and_remember(query: Query, solutions: Sequence[Solution]) -> Solution:
        chosen = choose(query, solutions)
        serving[relation_name(query)] = frozenset(from_solution(chosen, query).components)
        return chosen

    flow, unresolved = plan_flows(srg, templates, queries, choose_and_remember)
    return Plan(flow, names, {**unsolved, **unresolved}, serving)
