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


class StaleJoins:
    """Which frames the live ``srg`` joins, and which its ``stale`` edges would join besides:
    the connected components of both, found once per answer round (O(frames + edges)), so that
    each unsolved relation costs O(stale edges) (:meth:`waiting_for`), not a pass over the
    SRG."""

    def __init__(self, srg: nx.MultiDiGraph, stale: StaleEdges) -> None:
        self.stale = stale
        live = srg.to_undirected(as_view=True)
        self._live = _component_of(live)
        with_stale = nx.Graph(live)
        with_stale.add_edges_from(stale.values())
        self._with_stale = _component_of(with_stale)

    def waiting_for(self, relation: RelationId) -> list[str]:
        """The stale edges whose data would join the frames of an unsolved ``relation`` that
        the live SRG (without them) leaves apart or without one of them: those of the stale
        edges' component that holds both frames, sorted; none if no such component holds
        both, or if they are joined already (the planner's reason is then another)."""
        if _together(self._live, relation) or not _together(self._with_stale, relation):
            return []
        component = self._with_stale[relation.source]
        return sorted(e for e, (u, _) in self.stale.items() if self._with_stale[u] == component)


def _component_of(graph: nx.Graph) -> dict[str, int]:
    """The index of each frame's connected component."""
    return {
        frame: index
        for index, frames in enumerate(nx.connected_components(graph))
        for frame in frames
    }


def _together(component_of: Mapping[str, int], relation: RelationId) -> bool:
    """Whether both frames of ``relation`` lie in one component."""
    source, target = component_of.get(relation.source), component_of.get(relation.target)
    return source is not None and source == target


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
    stale edges would join (:class:`StaleJoins`, on the live ``srg`` the plan was made on) is
    answered as waiting for their data. O(relations + frames + edges)."""
    answers = {}
    joins = StaleJoins(srg, stale) if srg is not None and stale and plan.unsolved else None
    for relation in relations:
        name = plan_name(relation)
        reason = plan.unsolved.get(name)
        served = reason is None and name in plan.relations
        components = sorted(plan.serving.get(name, ())) if served else []
        blocked = joins.waiting_for(relation) if reason and joins is not None else []
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
