"""Plan every queried relation on the live SRG and merge the flows (sharing, section 5.1)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import networkx as nx

from ..dataflow import DataFlow, plan_flows, relation_name
from ..keys import RelationId
from ..planner import PlanningError, Query
from ..templates import Template


@dataclass(frozen=True)
class Plan:
    """The merged data flow serving every plannable relation (by the data flow's relation
    names, e.g. ``"C->A:6D"``), and the relations that cannot be planned with the reason."""

    flow: DataFlow
    relations: dict[str, RelationId] = field(default_factory=dict)
    unsolved: dict[str, str] = field(default_factory=dict)


def plan_relations(
    srg: nx.MultiDiGraph, templates: Sequence[Template], relations: Iterable[RelationId]
) -> Plan:
    """Best derivation of each relation (``dataflow.plan_flows``), merged into one data flow."""
    queries, names, unsolved = [], {}, {}
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
        queries.append(query)
    flow, unresolved = plan_flows(srg, templates, queries)
    return Plan(flow, names, {**unsolved, **unresolved})
