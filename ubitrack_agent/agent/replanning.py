"""Incremental replanning: an event replans only the relations it can affect (issue [scale]).

The planner derives a relation from the SRG restricted to the frames that can lie on one of its
derivations (``graph.planner.relevant_frames``: the biconnected block of ``source`` and
``target`` within ``slack`` hops of detour, the paper's "finding the relevant subgraph" of
section 5), so its answer depends only on that *region* and the edges within it. Between two
SRGs (any batch of events: providers or edges appearing or vanishing, edges going stale or
coming back, queries coming or going) a relation is planned again only when

* it is new (a query came);
* a worker nothing ran appeared (``appeared``) that is a component of one of its derivations
  within the cost margin (``RelationPlan.candidates``): the stable choice
  (``flows.stable_choice``) prefers running components among those derivations only, so for
  any other relation the new worker changes nothing (an unknown worker that is merely claimed
  or stopped replans none);
* its running derivation reads a removed (or changed) edge;
* an added (or changed) edge lies within its region on the new SRG, or the region itself
  changed (an added edge can shorten the way between the query's frames): the new edge may
  make it solvable, or cheaper (whether by more than the hysteresis margin,
  ``flows.stable_choice`` decides, as when the relation is planned first);
* it is unsolved because its frames are absent or not connected: it is planned again on any
  change (cheap: the planner fails on the first search of the frames).

A removed edge a derivation does not read leaves the chosen derivation valid and no worse
than the other ones left, so the choice stands; the relation's region is computed again if
the edge lay within it (the next addition is checked against the region that holds then).
Every other relation keeps its :class:`~.flows.RelationPlan` (the same object, and so the
same workers), and when no relation changed the merged :class:`~.flows.Plan` is the previous
object.

Which regions an addition can reach is first narrowed by one breadth-first search from the
added edges' frames (an edge within a region has both frames within the region's hop bound
``d(source, target) + slack`` of the query's frames, and that bound only shrinks as edges are
added), then decided exactly by computing the candidates' regions again.

Cost per event, for ``Q`` relations and ``E`` edges: O(E) to compare the SRGs (O(changed edges)
when the caller knows the changes: ``agent.live_srg``), O(ball) for the
search around the added edges, O(region) per candidate, O(Q) to find the relations a new
worker may serve, and one planner call per relation replanned (``graph.planner.plan``, or a
memo of it that answers unchanged regions at O(region): ``agent.plan_memo``), plus
O(components) to merge the flows when any changed.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence, Set
from dataclasses import dataclass, field
from typing import Any

import networkx as nx

from ubitrack_agent.agent.flows import Plan, Planner, RelationPlan, combine, plan_relation
from ubitrack_agent.agent.spares import DEFAULT_REDUNDANCY, Redundancy
from ubitrack_agent.graph.planner import (
    DEFAULT_SLACK,
    PlanningError,
    Query,
    introducible_frames,
    plan,
    relevant_frames,
)
from ubitrack_agent.graph.srg import new_srg, remove_static_relation
from ubitrack_agent.graph.templates import Template
from ubitrack_agent.graph.ways import either_way, hop_distances
from ubitrack_agent.net.keys import RelationId

Edges = Mapping[str, tuple[str, str]]
"""Edge ids with their frames ``(source, target)``."""


@dataclass(frozen=True)
class Region:
    """The frames the planner considers for a relation (``None``: its frames are absent or not
    connected) and the hop bound ``d(source, target) + slack`` within which they lie (infinite
    when unknown: the relation is then a candidate for every addition)."""

    frames: frozenset[str] | None
    bound: float = math.inf


NEVER = Region(frozenset(), -1.0)
"""The region of a relation the planner never takes (its type): no event replans it."""


@dataclass(frozen=True)
class Planned:
    """The planning state: the SRG planned on, each relation's part and region, the merged
    plan."""

    srg: nx.MultiDiGraph = field(default_factory=new_srg)
    parts: Mapping[RelationId, RelationPlan] = field(default_factory=dict)
    regions: Mapping[RelationId, Region] = field(default_factory=dict)
    plan: Plan = field(default_factory=lambda: combine(()))
    replanned: frozenset[RelationId] = frozenset()
    """The relations this step planned (for the counters and the benchmark)."""


def region_of(srg: nx.MultiDiGraph, templates: Sequence[Template], relation: RelationId) -> Region:
    """The region ``graph.planner.plan`` restricts ``relation``'s search to on ``srg`` (a
    recalibration's on ``srg`` without its relation's static edges, as ``flows.plan_relation``
    plans it). O(neighbourhood of the query's frames)."""
    try:
        query = Query(relation.source, relation.target, relation.type, relation.static)
    except PlanningError:
        return NEVER
    if relation.recalibrate:
        srg = remove_static_relation(srg, relation.source, relation.target)
    new = introducible_frames(srg, templates, query)
    try:
        frames = relevant_frames(srg, query.source, query.target, DEFAULT_SLACK, new)
    except PlanningError:
        return Region(None)
    if new:
        return Region(frozenset(frames))
    around = either_way(srg)
    inside = hop_distances(lambda f: (n for n in around(f) if n in frames), (query.source,))
    hops = inside.get(query.target, math.inf)
    return Region(frozenset(frames), hops + DEFAULT_SLACK)


def edge_changes(before: nx.MultiDiGraph, after: nx.MultiDiGraph) -> tuple[Edges, Edges]:
    """The edges of ``before`` gone from ``after`` and those ``after`` added, by id; an edge
    whose frames or attributes changed counts as both. O(edges)."""
    old = _edges(before)
    new = _edges(after)
    removed = {key: (u, v) for key, (u, v, data) in old.items() if new.get(key) != (u, v, data)}
    added = {key: (u, v) for key, (u, v, data) in new.items() if old.get(key) != (u, v, data)}
    return removed, added


def _edges(srg: nx.MultiDiGraph) -> dict[str, tuple[str, str, dict[str, Any]]]:
    return {key: (u, v, data) for u, v, key, data in srg.edges(keys=True, data=True)}


def affected(
    previous: Planned,
    srg: nx.MultiDiGraph,
    templates: Sequence[Template],
    relations: Set[RelationId],
    changes: tuple[Edges, Edges] | None = None,
    appeared: Set[str] = frozenset(),
) -> tuple[set[RelationId], dict[RelationId, Region]]:
    """The relations among ``relations`` that the change from ``previous.srg`` to ``srg``, and
    the workers that ``appeared``, can affect (module docstring), and the regions on ``srg``
    of those known (all but the affected ones whose region was not computed again);
    ``changes``, the edges removed and added, if known (``agent.live_srg``), saves comparing
    the SRGs."""
    removed, added = changes if changes is not None else edge_changes(previous.srg, srg)
    todo = {
        r
        for r in relations
        if r not in previous.parts or not previous.parts[r].candidates.isdisjoint(appeared)
    }
    regions = {r: previous.regions[r] for r in relations if r in previous.parts}
    if not removed and not added:
        return todo, regions
    for relation, region in regions.items():
        if region.frames is None or not previous.parts[relation].edges.isdisjoint(removed):
            todo.add(relation)
    computed = _check_additions(srg, templates, added, regions, todo) if added else set()
    for relation, region in regions.items():
        if relation in todo or region.frames is None:
            continue
        if any(u in region.frames and v in region.frames for u, v in removed.values()):
            regions[relation] = region_of(srg, templates, relation)
            computed.add(relation)
            if previous.parts[relation].unsolved is not None and regions[relation] != region:
                todo.add(relation)  # the reason names the frames it considered
    return todo, {r: g for r, g in regions.items() if r not in todo or r in computed}


def _check_additions(
    srg: nx.MultiDiGraph,
    templates: Sequence[Template],
    added: Edges,
    regions: dict[RelationId, Region],
    todo: set[RelationId],
) -> set[RelationId]:
    """Add to ``todo`` the relations an added edge lies within the region of (or whose region
    changed), updating ``regions``: a breadth-first search from the added edges' frames keeps
    the candidates whose frames are within their hop bound of them (module docstring). The
    relations whose region it computed again."""
    open_regions = {r: g for r, g in regions.items() if r not in todo and g.bound >= 0}
    finite = [g.bound for g in open_regions.values() if math.isfinite(g.bound)]
    ends = {frame for edge in added.values() for frame in edge}
    near = hop_distances(either_way(srg), (e for e in ends if e in srg), max(finite, default=0))
    computed = set()
    for relation, region in open_regions.items():
        reach = near.get(relation.source, math.inf) + near.get(relation.target, math.inf)
        if reach > region.bound:
            continue
        now = region_of(srg, templates, relation)
        regions[relation] = now
        computed.add(relation)
        inside = now.frames is not None and any(
            u in now.frames and v in now.frames for u, v in added.values()
        )
        if inside or now != region:
            todo.add(relation)
    return computed


def replan(
    previous: Planned | None,
    srg: nx.MultiDiGraph,
    templates: Sequence[Template],
    relations: Iterable[RelationId],
    running: Set[str] = frozenset(),
    follow: bool = True,
    appeared: Set[str] = frozenset(),
    changes: tuple[Edges, Edges] | None = None,
    planner: Planner = plan,
    redundancy: Redundancy = DEFAULT_REDUNDANCY,
) -> Planned:
    """The plan of ``relations`` on ``srg``, planning again (with ``planner``) only the
    relations the change since ``previous`` and the workers that ``appeared`` can affect (all
    of them if there is no ``previous``); the others keep their part. Choices follow
    ``flows.stable_choice`` with the ``running`` components (``appeared`` among them) and, if
    ``follow``, the previous plan's derivations (a standby agent, which follows what runs,
    passes ``False``); ``changes`` as for :func:`affected`; ``redundancy``: the spares and
    replicas each derivation gets (``agent.spares``)."""
    relations = set(relations)
    if previous is None:
        todo, regions = set(relations), {}
    else:
        todo, regions = affected(previous, srg, templates, relations, changes, appeared)
    base = previous or Planned()
    kept = base.plan.kept if follow and previous is not None else None
    parts = {r: base.parts[r] for r in relations if r not in todo}
    for relation in todo:
        parts[relation] = plan_relation(
            srg, templates, relation, running, kept, planner, redundancy
        )
        if relation not in regions:
            regions[relation] = region_of(srg, templates, relation)
    if previous is not None and parts.keys() == previous.parts.keys() and not todo:
        plan = previous.plan  # nothing changed: the same plan object
    else:
        plan = combine(parts.values())
    return Planned(srg, parts, regions, plan, frozenset(todo))
