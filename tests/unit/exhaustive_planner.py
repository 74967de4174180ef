"""The planner's search as it was before issue [scale], kept as the oracle of
``test_planner_oracle.py`` and nowhere else.

It saturates the whole region (no chain is pruned for lying off every way of the query, no
region is cut into parts; chains only towards the query target, as then) and expands every
maximal clique of compatible copies
(Bron-Kerbosch, :func:`networkx.find_cliques`): exponential in the redundancy, exact within
the paper's bookkeeping and the ``per_relation`` bound.
"""

from __future__ import annotations

import networkx as nx

from ubitrack_agent.graph.matcher import EdgeIndex, Match, compatible
from ubitrack_agent.graph.planner import (
    DEFAULT_PER_RELATION,
    DEFAULT_SLACK,
    NoSolutionError,
    Query,
    Solution,
    introducible_frames,
    relevant_frames,
    saturate,
    solutions,
)
from ubitrack_agent.graph.templates import Template


def every_maximal_clique(members: list[Match], index: EdgeIndex) -> list[list[Match]]:
    """Every inclusion-maximal set of pairwise compatible occurrences."""
    graph = nx.Graph()
    graph.add_nodes_from(range(len(members)))
    for i, a in enumerate(members):
        for j in range(i + 1, len(members)):
            if compatible(a, members[j], index):
                graph.add_edge(i, j)

    def by_canon(i: int) -> list[str]:
        return [index.edges[e].canon for e in members[i].edges]

    return [[members[i] for i in sorted(c, key=by_canon)] for c in nx.find_cliques(graph)]


def plan(
    srg: nx.MultiDiGraph,
    templates: list[Template],
    query: Query,
    per_relation: int = DEFAULT_PER_RELATION,
) -> list[Solution]:
    """Every solution of ``query`` found by the exhaustive search, best first."""
    new = introducible_frames(srg, templates, query)
    frames = relevant_frames(srg, query.source, query.target, DEFAULT_SLACK, new)
    rigid = [(query.source, query.target)] if query.static else []
    goal = (query.source, query.target)
    ws = saturate(
        srg,
        templates,
        frames,
        query.type,
        rigid,
        per_relation,
        goal,
        new,
        prune=False,
        copies=every_maximal_clique,
        either_way=False,
    )
    found = solutions(ws, query)
    if not found:
        raise NoSolutionError(f"no derivation of {query}")
    return found
