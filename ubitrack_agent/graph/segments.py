"""Cut frames: where a query's region falls apart into parts planned one by one.

The region of a query ``S -> T`` (:func:`ubitrack_agent.graph.planner.relevant_frames`) holds
the frames on simple paths between the two. Its blocks (biconnected components; Hopcroft and
Tarjan 1973, as :func:`networkx.biconnected_components` computes them) then lie in a row from
``S`` to ``T``, and consecutive blocks share one frame, a *cut frame*: every way from ``S`` to
``T`` passes it. A room hanging off a building frame is such a row: the room's block, the
survey edges, the other room's block.

The parts are planned apart, and a derivation of ``S -> T`` is a chain of derivations
``S -> c1``, ``c1 -> c2``, ... ``ck -> T``, one per part, whose sources are disjoint. Planning
the parts apart makes the cost a sum over rooms instead of a product: the alternatives of one
room no longer multiply with those of the next.

It is not exact. Fusing two ways, or estimating a pose from corresponding points, needs two
ways that share no edge, and two such ways may both pass a cut frame: two parallel chains
through it fused as wholes, where the parts fuse each side apart. The parts' derivation is
never worse in variance (joining the two ways at the cut frame can only lower it: Rayleigh's
monotonicity law of series and parallel variances, as of resistances), but it may take one
more fusion step at each cut frame with parallel ways on both sides (0.01 to 0.03 in cost:
a random graph planned 2.42 where the old search, one piece, planned 2.41). Cutting only where
one side is a single edge made that exact and a corridor of five rooms five times slower.

A cut frame is used only where the chain through it is a pose chain: every SRG edge at it is
6D (not an image plane or a feature, where a pattern on points or features joins the two
sides), and the query is 6D.
"""

from __future__ import annotations

from collections.abc import Iterable
from itertools import pairwise

import networkx as nx


def _row(region: nx.Graph, source: str, target: str) -> list[set[str]]:
    """The blocks of ``region`` from the one holding ``source`` to the one holding ``target``,
    in order along the block-cut tree: ``O(frames + edges)``."""
    blocks = [set(b) for b in nx.biconnected_components(region)]
    tree = nx.Graph()
    for i, block in enumerate(blocks):
        for frame in block:
            tree.add_edge(("block", i), ("frame", frame))
    path = nx.shortest_path(tree, ("frame", source), ("frame", target))
    return [blocks[i] for kind, i in path if kind == "block"]


def cut_frames(
    srg: nx.MultiDiGraph, frames: Iterable[str], source: str, target: str
) -> list[tuple[str, str, set[str]]]:
    """The parts of the region ``frames`` between ``source`` and ``target``: ``(from, to,
    frames)`` in order, split at every cut frame whose SRG edges in the region are all 6D.
    A single part (the whole region) when there is no such frame."""
    frames = set(frames)
    region = nx.Graph()
    region.add_nodes_from(frames)
    # the adjacency read directly: a networkx subgraph view holds a reference cycle, left to
    # the cyclic collector after every plan
    region.add_edges_from((u, v) for u in frames for v in srg.succ[u] if v in frames)
    if not nx.has_path(region, source, target):
        return [(source, target, frames)]
    row = _row(region, source, target)
    parts: list[tuple[str, str, set[str]]] = []
    start, held = source, set()
    for block, after in pairwise(row):
        held |= block
        (cut,) = block & after
        if _poses_only(srg, frames, cut):
            parts.append((start, cut, held))
            start, held = cut, set()
    parts.append((start, target, held | row[-1]))
    return parts


def _poses_only(srg: nx.MultiDiGraph, frames: set[str], frame: str) -> bool:
    """Every SRG edge at ``frame`` to a frame of the region is 6D."""
    return all(
        data["type"] == "6D"
        for neighbours in (srg.succ[frame], srg.pred[frame])
        for other, parallel in neighbours.items()
        if other in frames
        for data in parallel.values()
    )
