"""Frames on short ways: the frames of a region a derivation of a dynamic query can pass.

The region of a query ``S -> T`` (:func:`ubitrack_agent.graph.planner.relevant_frames`) keeps a
frame ``n`` when ``hops(S, n) + hops(n, T)`` is within ``slack`` hops of a shortest path. That
is a lower bound of the shortest *simple* way through ``n``: near a hub (a building frame every
room is surveyed to) each frame is two hops from both query frames, through the hub both
times, while every simple way through it goes round the building. A chain of a dynamic query
must lie on a way without a cycle (:meth:`ubitrack_agent.graph.planner.Workspace._on_a_way`),
so such a frame only costs the planner matches it rejects.

:func:`short_way_frames` keeps the frames on a simple path from ``S`` to ``T`` no longer than
the ways a chain may lie on (the span of the query plus the slack): a depth-first enumeration
of those paths, each step pruned by the remaining distance to ``T`` (breadth-first,
``O(frames + edges)``). The paths may be many
(``O(d**L)`` for degree ``d`` and length ``L``, e.g. ways through every body a room's trackers
see), so the enumeration stops after ``budget`` steps and the region is kept whole: the answer
is never smaller than the exact set, only sometimes larger. The budget grows with the region
(``STEPS_PER_FRAME`` steps per frame, at least ``DEFAULT_BUDGET``), so the enumeration stays
``O(frames)`` and a large region is not given up only for its size: around the building frame
of a corridor of 2,000 rooms, whose 2,000 neighbours are each tried, it takes 20,000-40,000
steps, and the region kept whole (2,012 frames instead of 18) did not plan in 20 s.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable

import networkx as nx

DEFAULT_BUDGET = 20_000
"""Most steps of the enumeration before a region of up to ``DEFAULT_BUDGET / STEPS_PER_FRAME``
frames is kept whole."""
STEPS_PER_FRAME = 50
"""Steps of the enumeration allowed per frame of a larger region."""


def either_way(srg: nx.MultiDiGraph) -> Callable[[str], Iterable[str]]:
    """A frame's neighbours in ``srg``, whichever way their edges point."""
    succ, pred = srg.succ, srg.pred
    return lambda node: (*succ[node], *pred[node])


def hop_distances(
    around: Callable[[str], Iterable[str]],
    starts: Iterable[str],
    limit: float = math.inf,
    goal: str | None = None,
    slack: int = 0,
    avoid: frozenset[str] = frozenset(),
) -> dict[str, int]:
    """Hops from the nearest of ``starts`` (breadth-first over the neighbours ``around``
    gives), up to ``limit`` hops, or up to ``slack`` hops beyond the distance of ``goal`` once
    it is reached, never entering a frame of ``avoid``. ``O(frames + edges)`` visited."""
    dist = dict.fromkeys(starts, 0)
    frontier = list(dist)
    depth = 0
    while frontier and depth < limit:
        if goal in dist:
            limit = min(limit, dist[goal] + slack)
            if depth >= limit:
                break
        depth += 1
        nxt = []
        for node in frontier:
            for other in around(node):
                if other not in dist and other not in avoid:
                    dist[other] = depth
                    nxt.append(other)
        frontier = nxt
    return dist


def short_way_frames(
    around: Callable[[str], Iterable[str]],
    frames: set[str],
    source: str,
    target: str,
    longest: float,
    budget: int | None = None,
) -> set[str]:
    """The frames of ``frames`` on a simple path from ``source`` to ``target`` of at most
    ``longest`` hops, over the neighbours ``around`` gives (module docstring); ``frames``
    itself if the enumeration takes more than ``budget`` steps (by default ``STEPS_PER_FRAME``
    per frame, at least ``DEFAULT_BUDGET``) or the two are not connected."""
    if budget is None:
        budget = max(DEFAULT_BUDGET, STEPS_PER_FRAME * len(frames))
    to_target = hop_distances(lambda node: (o for o in around(node) if o in frames), (target,))
    if source not in to_target:
        return frames
    limit = longest
    kept = {source, target}
    path = [source]
    on_path = {source}
    # iterative depth-first search: a stack of neighbour iterators, one per frame on the path
    stack = [iter(around(source))]
    steps = 0
    while stack:
        steps += 1
        if steps > budget:
            return frames
        nxt = next(stack[-1], None)
        if nxt is None:
            stack.pop()
            on_path.discard(path.pop())
            continue
        if nxt in on_path or nxt not in to_target or len(path) + to_target[nxt] > limit:
            continue
        if nxt == target:
            kept.update(path)
            continue
        path.append(nxt)
        on_path.add(nxt)
        stack.append(iter(around(nxt)))
    return kept
