"""The agent's answer to each query: which flow serves it, or why none can (issue 14, item 1).

The active agent publishes what :func:`query_answers` returns (wire format and keys:
:mod:`ubitrack_agent.net.answer`), so an application learns why nothing arrives without
reading the agent's log. Pure: the runtime publishes.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import networkx as nx

from ubitrack_agent.agent.flows import Plan, plan_name
from ubitrack_agent.net.answer import NOT_PLANNED, Answer
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.spec import ComponentSpec

StaleEdges = Mapping[str, tuple[str, str]]
"""The stale edges (``agent.liveness``) by id, each with its two frames."""


def stale_edges(
    fragments: Mapping[str, list[dict[str, Any]]], stale: Iterable[str]
) -> dict[str, tuple[str, str]]:
    """The frames of each of the ``stale`` edge ids among the accepted ``fragments``."""
    wanted = set(stale)
    return {
        entry["id"]: (entry["from"], entry["to"])
        for entries in fragments.values()
        for entry in entries
        if entry["id"] in wanted
    }


def waiting_for(srg: nx.MultiDiGraph, stale: StaleEdges, relation: RelationId) -> list[str]:
    """The stale edges whose data would join the frames of an unsolved ``relation`` that the
    live ``srg`` (without them) leaves apart or without one of them: those of the stale
    edges' component that holds both frames, sorted; none if no such component holds both,
    or if they are joined already (the planner's reason is then another). ``O(frames +
    edges)``: a union of the live SRG's and the stale edges' components."""
    ends = (relation.source, relation.target)
    joined = all(f in srg for f in ends) and nx.has_path(srg.to_undirected(as_view=True), *ends)
    if joined or not stale:
        return []
    graph = nx.Graph(srg.to_undirected(as_view=True))
    graph.add_edges_from(stale.values())
    if not all(f in graph for f in ends) or not nx.has_path(graph, *ends):
        return []
    component = nx.node_connected_component(graph, relation.source)
    return sorted(edge_id for edge_id, (u, _) in stale.items() if u in component)


def query_answers(
    plan: Plan,
    relations: Iterable[RelationId],
    keys: KeySpace,
    wanted: Mapping[str, ComponentSpec],
    srg: nx.MultiDiGraph | None = None,
    stale: StaleEdges | None = None,
) -> dict[str, str]:
    """The answer to each of ``relations`` under ``plan`` (``wanted``: the component
    specifications of the plan), encoded, by answer key. An unsolved relation whose frames
    stale edges would join (:func:`waiting_for`, on the live ``srg`` the plan was made on) is
    answered as waiting for their data."""
    answers = {}
    for relation in relations:
        name = plan_name(relation)
        reason = plan.unsolved.get(name)
        served = reason is None and name in plan.relations
        components = sorted(plan.serving.get(name, ())) if served else []
        blocked = waiting_for(srg, stale, relation) if reason and srg is not None and stale else []
        if blocked:
            reason = f"waiting for data on {', '.join(blocked)} (stale); until then: {reason}"
        answer = Answer(
            relation=str(relation),
            served=served,
            key=keys.relation(relation),
            reason=None if served else reason or NOT_PLANNED,
            components={i: wanted[i].service for i in components if i in wanted},
            waiting=bool(blocked),
        )
        answers[keys.answer(relation)] = answer.encode()
    return answers
