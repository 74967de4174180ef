"""The controller (paper section 5): plan the best derivation of a queried spatial relationship.

For a query ``(from, to, type, static)`` the planner

1. restricts the SRG to the frames that can take part in a derivation (:func:`relevant_frames`:
   the biconnected block joining the two frames, minus detours longer than ``slack`` hops, the
   reduction section 5.1 suggests for large graphs; for a dynamic query, only the frames on a
   simple way that short, :mod:`.ways`),
2. for a dynamic 6D query whose region falls apart at cut frames (:mod:`.segments`: blocks in
   a row, Hopcroft and Tarjan 1973), plans each part on its own and chains the parts'
   derivations (:func:`_plan_parts`; parts shared across plans through a :class:`PartCache`),
3. applies every template repeatedly (forward chaining with the matcher of
   :mod:`ubitrack_agent.graph.matcher`) until no new, non-redundant edge can be inferred, keeping
   the bookkeeping of section 5.1 (sources, canonical computation, dominance) and adding only edges
   that serve the query (useful types, calibration of unknown rigid relations only, chains
   towards the query, :meth:`Workspace._wanted`, and for a dynamic query only chains that can
   lie on a way of it, :meth:`Workspace.viable_chain`, their last link tested before it is
   bound, :meth:`Workspace.last_link`); what a full relation would turn down is not formed
   (a chain no cheaper than its dearest alternative, :meth:`Workspace._chain_outclassed`, a
   large group of copies whose cost floor is not, :meth:`Workspace.group_outclassed`),
4. returns every distinct derivation of the queried edge, best first by the cost model below,
   equally dear ones (and the choices between them while searching: which alternative a full
   relation drops, which bracketing of a computation keeps its slot, the copies' order) by
   what they compute (:func:`_signature`), not by the ids of their steps, which count the
   steps made before them.

The cost of a plan grows with what a part of the region holds, polynomially (``docs/planner.md``,
"Complexity and guarantees"), and linearly with the parts a query crosses.

A static query may name a frame the SRG lacks: a calibration introduces it (the tip of a tip
calibration, :func:`introducible_frames`; ``docs/planner.md``, "Frames introduced by a
calibration").

Cost model (``docs/planner.md``): each edge carries an expected error variance (m^2), a latency
and the sensors and steps it uses. Variances propagate per template rule (``sum`` for inversion,
concatenation and calibrations, inverse-variance ``fusion``, ``pooled`` for point-correspondence
algorithms), and the scalar cost of an edge is::

    cost = variance / SIGMA_REF**2 + latency / LATENCY_REF
           + SENSOR_WEIGHT * sensors + STEP_WEIGHT * steps

so fusion of independent paths is chosen when it lowers the expected error by more than the
price of the extra sensors and steps.
"""

from __future__ import annotations

import hashlib
import math
import sys
from collections import OrderedDict, defaultdict
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from itertools import product
from typing import Any

import networkx as nx

from ubitrack_agent.core.heap import collector_paused
from ubitrack_agent.graph.matcher import (
    EXACT_COPIES,
    CopySets,
    EdgeIndex,
    EdgeRecord,
    Instance,
    LastLink,
    LastTest,
    Match,
    Viable,
    copy_sets,
    expand_group,
    find_matches,
    group_key,
    time_expandable,
)
from ubitrack_agent.graph.segments import cut_frames
from ubitrack_agent.graph.srg import EDGE_TYPES, EdgeAttrs, Quality, check_node_name, edge_ids
from ubitrack_agent.graph.templates import CostSpec, InputSpec, Template
from ubitrack_agent.graph.ways import either_way, hop_distances, short_way_frames

SIGMA_REF = 1e-3
"""Reference error (m): a variance of SIGMA_REF**2 costs 1."""
LATENCY_REF = 0.01
"""Reference latency (s): LATENCY_REF of latency costs 1."""
SENSOR_WEIGHT = 0.1
"""Cost of each distinct provider (sensor, database) a derivation depends on."""
STEP_WEIGHT = 0.01
"""Cost of each pattern step (a running component) of a derivation."""
DEFAULT_SLACK = 2
"""Longest detour (hops beyond a shortest path) a derivation may take through the SRG."""
NARROWED_MEMO_SIZE = 64
"""Most candidate lists a :class:`_MemoisedNarrowing` remembers (a list made afresh for each
call is remembered too, until the memo is full and cleared)."""
DEFAULT_PER_RELATION = 8
"""Most alternatives kept per (from, to, type, static) relation during planning."""
VARIANCE_FLOOR = 1e-30
"""Smallest variance (m^2) fusion divides by: a measured edge may announce sigma 0."""
_TIE = 1e-9


class PlanningError(ValueError):
    """A query cannot be planned; the message says why (unknown or unconnected frames...)."""


class NoSolutionError(PlanningError):
    """The queried relationship cannot be derived from the SRG with the templates."""


@dataclass(frozen=True)
class Query:
    """A queried relationship: ``source -> target`` of ``type``; ``static`` asks for a static
    edge (and declares the two frames rigidly connected, which enables calibration patterns)."""

    source: str
    target: str
    type: str
    static: bool = False

    def __post_init__(self) -> None:
        check_node_name(self.source, "query --from")
        check_node_name(self.target, "query --to")
        if self.source == self.target:
            raise PlanningError("query: --from and --to must be different frames")
        if self.type not in EDGE_TYPES:
            raise PlanningError(f"query: unknown type {self.type!r}, expected {sorted(EDGE_TYPES)}")


@dataclass(frozen=True)
class Step:
    """One applied pattern instance. ``outputs`` are ``(name, from, to, type, edge id)``; the id
    is ``None`` for an output not added to the SRG: already measured (e.g. R->O of hand-eye),
    not rigid (the pivot T->P of a tip calibration queried from the marker), or not useful."""

    id: str
    template: Template
    expansion: str
    inputs: tuple[tuple[str, tuple[str, ...]], ...]
    outputs: tuple[tuple[str, str, str, str, str | None], ...]


@dataclass(frozen=True)
class Solution:
    """A derivation of the queried edge: the edge, its steps in data-flow order and the records
    of every edge the steps read or write (by id)."""

    edge: EdgeRecord
    steps: tuple[Step, ...]
    records: Mapping[str, EdgeRecord]

    def as_json(self) -> dict[str, Any]:
        """The solution as the design tool prints it (``ubitrack plan --json``)."""

        def triple(edge_id: str) -> list[str]:
            record = self.records[edge_id]
            return [record.source, record.target, record.type]

        return {
            "cost": round(self.cost, 6),
            "static": self.static,
            "measured": [[e.source, e.target, e.type, e.provider] for e in self.measured()],
            "steps": [
                {
                    "pattern": step.template.pattern,
                    "expansion": step.expansion,
                    "inputs": [triple(e) for _, ids in step.inputs for e in ids],
                    "outputs": [[src, dst, typ] for _, src, dst, typ, _ in step.outputs],
                }
                for step in self.steps
            ],
        }

    def measured(self) -> list[EdgeRecord]:
        """The measured edges the solution reads (itself, if it is one), by frames and type."""
        measured = (record for record in self.records.values() if record.measured)
        return sorted(measured, key=lambda e: (e.source, e.target, e.type, e.provider, e.id))

    @property
    def cost(self) -> float:
        return self.edge.cost

    @property
    def static(self) -> bool:
        return self.edge.static


def _dominates(a: EdgeRecord, b: EdgeRecord) -> bool:
    """``a`` is no worse than ``b`` in any component of the cost vector (variance, latency,
    sensors, steps)."""
    qa, qb = a.quality, b.quality
    return (
        qa.variance <= qb.variance * (1 + _TIE)
        and qa.latency <= qb.latency * (1 + _TIE)
        and len(a.providers) <= len(b.providers)
        and len(a.steps) <= len(b.steps)
    )


def edge_cost(quality: Quality, providers: int, steps: int) -> float:
    """The scalar cost of an edge (module docstring)."""
    return (
        quality.variance / SIGMA_REF**2
        + quality.latency / LATENCY_REF
        + SENSOR_WEIGHT * providers
        + STEP_WEIGHT * steps
    )


def propagate(instance: Instance, records: dict[str, EdgeRecord]) -> Quality:
    """Quality of the outputs of ``instance`` from the quality of its inputs (cost model)."""
    return _propagated(instance, [records[e] for e in instance.input_edges()], records)


def _propagated(
    instance: Instance, inputs: Sequence[EdgeRecord], records: Mapping[str, EdgeRecord]
) -> Quality:
    """:func:`propagate`, given the records of the instance's inputs in input order."""
    spec = instance.template.cost
    corr = instance.template.correspondence
    if spec.rule == "fusion":  # an exact input (variance 0) makes the fusion exact, not 1/0
        variance = 1.0 / sum(1.0 / max(r.quality.variance, VARIANCE_FLOOR) for r in inputs)
    elif spec.rule == "pooled" and corr is not None:
        variances = {n: [records[e].quality.variance for e in ids] for n, ids in instance.inputs}
        fixed = sum(v for n, vs in variances.items() if n not in corr.edges for v in vs)
        copies = len(variances[corr.edges[0]])
        per_copy = sum(sum(variances[n]) for n in corr.edges) / copies
        scale = corr.multiplicity.lo / copies if instance.expansion == "space" else 1.0
        shared = min(_shared_variance(instance, records), per_copy)
        variance = fixed + shared + (per_copy - shared) * scale
    else:
        variance = sum(r.quality.variance for r in inputs)
    variance = _gained(variance, spec, instance.expansion)
    rates = [e.quality.rate for e in inputs if e.mode == "push" and e.quality.rate > 0]
    latency = max(e.quality.latency for e in inputs) + spec.latency
    return Quality(variance, min(rates, default=0.0), latency)


def _summed_cost(template: Template, inputs: Sequence[EdgeRecord]) -> float:
    """The cost :meth:`Workspace.apply` gives the outputs of an unexpanded instance of a
    template whose rule is ``sum`` on ``inputs`` (in input order), computed the same way."""
    spec = template.cost
    quality = Quality(
        _gained(sum(r.quality.variance for r in inputs), spec, "none"),
        0.0,
        max(r.quality.latency for r in inputs) + spec.latency,
    )
    providers = frozenset().union(*(r.providers for r in inputs))
    steps = frozenset().union(*(r.steps for r in inputs))
    return edge_cost(quality, len(providers), len(steps) + 1)


def _gained(variance: float, spec: CostSpec, expansion: str) -> float:
    """A propagated variance times the template's gain (and ``time_gain`` in time)."""
    return variance * (spec.gain * (spec.time_gain if expansion == "time" else 1.0))


def _shared_variance(instance: Instance, records: Mapping[str, EdgeRecord]) -> float:
    """The variance of the measured edges every copy of a space-expanded correspondence
    derives from: an error they share moves all copies alike and does not average out (the
    points HT->Fi of section 4.2 all carry the error of ART->HT and ART->WT)."""
    corr = instance.template.correspondence
    if corr is None or instance.expansion != "space":
        return 0.0
    copies = zip(*(ids for name, ids in instance.inputs if name in corr.edges), strict=True)
    common = frozenset.intersection(
        *(frozenset().union(*(records[e].sources for e in copy)) for copy in copies)
    )
    return sum(records[e].quality.variance for e in common if e in records)


def useful_types(templates: Sequence[Template], wanted: str) -> frozenset[str]:
    """Edge types that can contribute to an edge of type ``wanted`` (section 5.1, "when to add
    new edges"): the closure of ``{wanted}`` under "some instantiation of a template has an
    output of a useful type, so all its input types are useful". A 6D query never needs 3R."""
    signatures = []
    for template in templates:
        names = list(template.type_vars)
        for combo in product(*(template.type_vars[n] for n in names)):
            binding = dict(zip(names, combo, strict=True))

            def resolve(edge_type: str, binding: dict[str, str] = binding) -> str:
                return binding[edge_type[1:]] if edge_type.startswith("$") else edge_type

            ins = {resolve(spec.type) for spec in template.inputs}
            outs = {resolve(spec.type) for spec in template.outputs}
            signatures.append((frozenset(ins), frozenset(outs)))
    useful = {wanted}
    changed = True
    while changed:
        changed = False
        for ins, outs in signatures:
            if outs & useful and not ins <= useful:
                useful |= ins
                changed = True
    return frozenset(useful)


def _span(
    srg: nx.MultiDiGraph,
    frames: set[str],
    goal: tuple[str, str],
    wanted: str,
    around: Callable[[str], Iterable[str]],
) -> float:
    """The hops of a shortest way between the goal's frames along edges of the ``wanted``
    type (a chain of them alone derives the query), or along any edge if there is none: the
    length the ways of :meth:`Workspace._on_a_way` may exceed by the slack. An edge of another
    type between the two (a point of the target seen from the source) derives no pose by itself,
    so it does not shorten the ways the slack is counted from. ``O(frames + edges)``."""
    source, target = goal
    along: dict[str, set[str]] = {f: set() for f in frames}
    for u, v, _, data in _edges_within(srg, frames):
        if data["type"] == wanted:
            along[u].add(v)
            along[v].add(u)
    hops = hop_distances(along.__getitem__, (source,), goal=target).get(target)
    if hops is None:

        def within(frame: str) -> Iterable[str]:
            return (other for other in around(frame) if other in frames)

        hops = hop_distances(within, (source,), goal=target).get(target)
    return math.inf if hops is None else hops


def _edges_within(
    srg: nx.MultiDiGraph, frames: set[str]
) -> Iterator[tuple[str, str, str, Mapping[str, Any]]]:
    """The SRG edges between ``frames`` (source, target, key, attributes), read off the
    adjacency directly (a subgraph view filters every access). ``O(edges at frames)``."""
    succ = srg.succ
    for u in frames:
        if u not in succ:  # a frame to be introduced
            continue
        for v, parallel in succ[u].items():
            if v in frames:
                for key, data in parallel.items():
                    yield u, v, key, data


def _chain_distances(
    srg: nx.MultiDiGraph, frames: set[str], goal: tuple[str, str]
) -> tuple[dict[str, int], dict[str, int]]:
    """Hop distances of ``frames`` from each query frame along 6D edges (the links of chains);
    frames without a 6D path come after all others, ordered by their distance along any edge.
    A query frame the SRG lacks (to be introduced by a calibration) has no distances of its
    own: it takes those of the other query frame, so only chains between frames at equal
    distance from it are left out."""
    joined: dict[str, set[str]] = {f: set() for f in frames}
    poses: dict[str, set[str]] = {f: set() for f in frames}
    for u, v, _, data in _edges_within(srg, frames):
        joined[u].add(v)
        joined[v].add(u)
        if data["type"] == "6D":
            poses[u].add(v)
            poses[v].add(u)
    near = {}
    for end in goal:
        if end in frames:
            anywhere = hop_distances(joined.__getitem__, (end,))
            along = hop_distances(poses.__getitem__, (end,))
            near[end] = {n: along.get(n, len(frames) + anywhere[n]) for n in frames}
    source, target = goal
    return near.get(source, near.get(target)), near.get(target, near.get(source))


def introducible_frames(
    srg: nx.MultiDiGraph, templates: Sequence[Template], query: Query
) -> tuple[str, ...]:
    """The query frame the SRG lacks that a calibration may introduce, or ``()``.

    A pattern introduces a frame through a role no input binds (:attr:`Template.introduced`,
    e.g. the tip of a tip calibration). Only a static query may name such a frame: it declares
    the frame rigid to the other query frame, which says where the new frame is attached (the
    tip to the pointer's marker, not to some other tracked body). The other frame must be in
    the SRG.
    """
    missing = tuple(n for n in (query.source, query.target) if n not in srg)
    if query.static and len(missing) == 1 and any(t.introduced for t in templates):
        return missing
    return ()


def relevant_frames(
    srg: nx.MultiDiGraph, source: str, target: str, slack: int, new_frames: Iterable[str] = ()
) -> set[str]:
    """Frames that can take part in a derivation of ``source -> target``.

    A frame lies on a simple path between the two frames iff it is in the biconnected block of
    ``G + {source-target}`` that holds the added edge; of those, frames on detours longer than
    ``slack`` hops beyond the shortest path are dropped. Only the neighbourhood of the two frames
    is visited. Raises :class:`NoSolutionError` naming the frames if they are absent or not
    connected.

    ``new_frames`` (from :func:`introducible_frames`) names a query frame absent from the SRG
    that a calibration may introduce. It counts as one hop from the other query frame, so the
    frame it is attached to lies within ``slack`` hops of that frame, and the frames measuring
    it one hop further: the frames within ``slack + 1`` hops are returned.
    """
    missing = [n for n in (source, target) if n not in srg and n not in new_frames]
    if missing:
        raise NoSolutionError(f"frame(s) {', '.join(missing)} not in the SRG")
    present = [n for n in (source, target) if n in srg]
    if len(present) == 1:
        return set(hop_distances(either_way(srg), present[:1], slack + 1))
    around = either_way(srg)
    from_source = hop_distances(around, (source,), goal=target, slack=slack)
    if target not in from_source:
        part_a = sorted(from_source)
        part_b = sorted(hop_distances(around, (target,)))
        raise NoSolutionError(
            f"frames {source} and {target} are not connected in the SRG: "
            f"{source} is connected to {{{', '.join(part_a)}}}, "
            f"{target} to {{{', '.join(part_b)}}}"
        )
    bound = from_source[target] + slack
    from_target = hop_distances(around, (target,), bound)
    near = {n for n, d in from_target.items() if d + from_source.get(n, bound + 1) <= bound}
    sub = nx.Graph()
    sub.add_edges_from((u, v) for u in near for v in (*srg.succ[u], *srg.pred[u]) if v in near)
    sub.add_edge(source, target)
    for block in nx.biconnected_components(sub):
        if source in block and target in block:
            return set(block)
    raise AssertionError("the added edge lies in exactly one block")


class _Bits(dict[str, int]):
    """A bit per frame, the next free one given to a frame on its first look-up."""

    def __missing__(self, frame: str) -> int:
        bit = self[frame] = 1 << len(self)
        return bit

    def cover(self, frames: Iterable[str]) -> None:
        """Give each of ``frames`` its bit."""
        for frame in frames:
            if frame not in self:
                self.__missing__(frame)


class _MemoisedNarrowing:
    """A narrowing of the matcher's candidate lists (:meth:`Workspace._narrowing`), each list's
    result remembered: the matcher offers the same list of the index (the edges at a frame
    every tracker joins) to every chain's last link there, and an index list only grows at its
    end until an edge is retired, so a list narrowed before is read again only for its new
    edges. Without this each narrowing read all K candidates, K times: O(K**2) per plan in a
    room with K trackers (six lists in 3,006 narrowings at K = 500), now O(K)
    (``docs/performance.md``, "Planner, session 27"). A list the matcher made afresh, or any
    list after a retirement, is narrowed whole; at most :data:`NARROWED_MEMO_SIZE` lists are
    remembered. It holds the index, not the workspace, so a plan's objects form no reference
    cycle and are freed as soon as the plan ends."""

    def __init__(self, index: EdgeIndex, kept: Callable[[Sequence[str]], list[str]]) -> None:
        self._index = index
        self._kept = kept
        self._memo: dict[int, tuple[Sequence[str], int, int, tuple[str, ...]]] = {}
        """By the list's id: the list, the retired edges' count and the list's length when
        narrowed, and what was kept."""

    def __call__(self, ids: Sequence[str]) -> tuple[str, ...]:
        retired = len(self._index.retired)
        memo = self._memo.get(id(ids))
        if memo is not None and memo[0] is ids and memo[1] == retired and memo[2] <= len(ids):
            if memo[2] == len(ids):
                return memo[3]
            result = memo[3] + tuple(self._kept(ids[memo[2] :]))
        else:
            result = tuple(self._kept(ids))
            if len(self._memo) >= NARROWED_MEMO_SIZE:
                self._memo.clear()
        self._memo[id(ids)] = (ids, retired, len(ids), result)
        return result


@dataclass
class Workspace:
    """The working SRG of one planning run: measured and inferred edges, and the steps."""

    index: EdgeIndex = field(default_factory=EdgeIndex)
    steps: dict[str, Step] = field(default_factory=dict)
    per_relation: int = DEFAULT_PER_RELATION
    by_relation: dict[tuple[str, str, str, bool], list[str]] = field(
        default_factory=lambda: defaultdict(list)
    )
    useful_types: frozenset[str] = EDGE_TYPES
    goal: tuple[str, str] | None = None
    distances: tuple[dict[str, int], dict[str, int]] = field(default_factory=lambda: ({}, {}))
    neighbours: dict[str, set[str]] = field(default_factory=dict)
    detour: int = DEFAULT_SLACK
    prefix: str = ""
    static_serves: bool = False
    either_way: bool = True
    """Chains either way round between the query frames (:meth:`_wanted`); ``False``: only
    towards the query target, the rule before session 15, which the test oracle keeps."""
    span: float = 0
    _by_class: dict[tuple[int, int], frozenset[str]] | None = None
    """:meth:`_classes`, once built."""
    _distances: dict[str, dict[str, int]] = field(default_factory=dict)
    _pair_hops: dict[tuple[str, str], int] = field(default_factory=dict)
    """:meth:`_distance` by frames."""
    _narrowers: dict[tuple, Callable[[Sequence[str]], Sequence[str]] | None] = field(
        default_factory=dict
    )
    """:meth:`_narrowing`'s functions by fixed end's class, type and free end."""
    _reach: dict[tuple[str, int], dict[int, int]] = field(default_factory=dict)
    """:meth:`_avoiding`'s hops (by frame bit) by start and frames avoided."""
    _counts: dict[str, tuple[list[int], list[int]]] = field(default_factory=dict)
    """:meth:`_shortest`'s hops and numbers of shortest ways, by start frame."""
    _bits: _Bits = field(default_factory=lambda: _Bits())
    """A bit per frame of the region, given on first use (frame sets as ints:
    :meth:`_on_a_way`)."""
    _adjacent: list[int] = field(default_factory=list)
    """The neighbours of the frame of each bit, as bits (:meth:`_avoiding`)."""
    _link_bits: dict[str, int] = field(default_factory=dict)
    """The frames each chained edge's sources join, as bits (by edge id)."""
    _ways: dict[tuple[str, str, int, float], bool] = field(default_factory=dict)
    """:meth:`_on_a_way` by chain ends, inside and hops left: many chains share them."""
    _goal_hops: tuple[dict[str, int], dict[str, int]] | None = None
    _copy_costs: dict[tuple[str, tuple[str, ...]], _CopyCost] = field(default_factory=dict)
    _writes: dict[tuple, tuple[tuple[str, str, str, tuple[bool, ...]], ...]] = field(
        default_factory=dict
    )
    """The relations each group of occurrences writes (:meth:`group_outclassed`)."""

    def _around(self, frame: str) -> Iterable[str]:
        return self.neighbours.get(frame, ())

    def _hops_to_goal(self) -> tuple[dict[str, int], dict[str, int]]:
        """Hops from the query's source and from its target (:meth:`_hops_from`), kept."""
        assert self.goal is not None
        self._goal_hops = (self._hops_from(self.goal[0]), self._hops_from(self.goal[1]))
        return self._goal_hops

    def _hops_from(self, a: str) -> dict[str, int]:
        """Hops from frame ``a`` to each frame of the region it reaches, either direction (BFS,
        ``O(frames + edges)`` once per frame)."""
        known = self._distances.get(a)
        if known is None:
            known = self._distances[a] = hop_distances(self._around, (a,))
        return known

    def _distance(self, a: str, b: str) -> int:
        """Hops between frames ``a`` and ``b`` in the region (more than any if not joined):
        breadth-first on bit sets (:attr:`_adjacent`) from ``a`` until ``b`` is reached,
        ``O(frames within that distance)`` word operations. A search of the whole region per
        step output's source was ``O(F (F + E))`` in all (514 searches of 512 frames in a room
        with 500 redundant trackers), where the frames of a step's output are mostly a hop or
        two apart. Not ``ways.hop_distances(..., goal=b)``: a level through a frame every one of K
        trackers joins costs K Python steps there, one integer operation here."""
        if a == b:
            return 0
        known = self._pair_hops.get((a, b))
        if known is None:
            start, target = self._bits[a], self._bits[b]
            known = next(
                (depth for depth, frontier in self._levels(start, 0) if frontier & target),
                len(self.neighbours) + 1,
            )
            self._pair_hops[a, b] = known
        return known

    def _frame_bits(self, link: EdgeRecord) -> int:
        """The frames ``link``'s sources join (:attr:`EdgeRecord.frames`) as bits, kept."""
        bits = self._link_bits.get(link.id)
        if bits is None:
            bits, table = 0, self._bits
            for frame in link.frames:
                bits |= table[frame]
            self._link_bits[link.id] = bits
        return bits

    def _avoiding(self, start: str, goal: str, avoid: int) -> float:
        """Hops from ``start`` to ``goal`` in the region without entering a frame of ``avoid``
        (bits, :attr:`_bits`; edges in either direction; infinite if there is no such way).

        Mostly a shortest way avoids them, and path counting shows it without a search of its
        own (Brandes 2001, "A faster algorithm for betweenness centrality": the shortest ways
        from s to g through v number ``sigma(s, v) * sigma(v, g)`` when ``d(s, v) + d(v, g) =
        d(s, g)``): if the ways through the avoided frames, summed over them, are fewer than
        all shortest ways, one avoids every one of them and the answer is ``d(s, g)``. That
        needs a counting search from ``start`` (:meth:`_shortest`, memoised; the caller puts a
        query frame there) and the ways from each avoided frame to ``goal``
        (:meth:`_ways_to`: mostly a hop or two, counted on the neighbours' bits), ``O(|avoid|)``
        per call; otherwise a breadth-first search on bit sets (:meth:`_hops_avoiding`) per
        distinct ``(start, avoid)``, memoised: in a room with 200 redundant trackers those
        were 9,754 searches of the 212 frames."""
        if start == goal:
            return 0
        goal_bit, start_bit = self._bits[goal], self._bits[start]
        if (start_bit | goal_bit) & avoid:
            return math.inf
        hops, paths = self._shortest(start)
        at = goal_bit.bit_length() - 1
        if at >= len(hops) or hops[at] < 0:
            return math.inf
        through, rest, length = 0, avoid, hops[at]
        while rest:
            low = rest & -rest
            v = low.bit_length() - 1
            if v < len(hops) and 0 <= hops[v] < length:
                through += paths[v] * self._ways_to(goal, v, length - hops[v])
            rest ^= low
        if through < paths[at]:
            return length
        adjacent = self._adjacent  # a frame whose every neighbour is avoided is cut off
        if not adjacent[start_bit.bit_length() - 1] & ~avoid or not adjacent[at] & ~avoid:
            return math.inf
        key = (start, avoid)
        known = self._reach.get(key)
        if known is None:
            known = self._reach[key] = self._hops_avoiding(start_bit, avoid)
        return known.get(goal_bit, math.inf)

    def _ways_to(self, goal: str, v: int, hops: int) -> int:
        """The number of ways of ``hops`` hops between ``goal`` and the frame of bit position
        ``v``, which is at least that far from it (by the triangle inequality, in
        :meth:`_avoiding`): 1 or 0 for one hop, their common neighbours for two (a popcount),
        else from a counting search from ``goal`` (:meth:`_shortest`, memoised). The avoided
        frames (a chain's inside) mostly lie a hop or two from the chain's end, so most chain
        ends need no counting search of their own: in a room with 500 redundant trackers
        one per frame was ``O(F (F + E))`` in all."""
        adjacent = self._adjacency()
        at = self._bits[goal].bit_length() - 1
        if hops == 1:
            return adjacent[v] >> at & 1
        if hops == 2:
            return (adjacent[v] & adjacent[at]).bit_count()
        back, back_paths = self._shortest(goal)
        return back_paths[v] if v < len(back) and back[v] == hops else 0

    def _adjacency(self) -> list[int]:
        """:attr:`_adjacent`, read again if a frame was given its bit since."""
        adjacent, table = self._adjacent, self._bits
        if len(adjacent) < len(table):
            table.cover(sorted(self.neighbours))
            adjacent[:] = [0] * len(table)
            for frame, bit in table.items():
                at = bit.bit_length() - 1
                for other in self.neighbours.get(frame, ()):
                    adjacent[at] |= table[other]
        return adjacent

    def _shortest(self, frame: str) -> tuple[list[int], list[int]]:
        """Hops from ``frame`` to each frame (by bit position; -1 if not reached) and the
        number of shortest ways to it: breadth-first with path counts (Brandes 2001),
        ``O(frames + edges)``, memoised per frame."""
        known = self._counts.get(frame)
        if known is not None:
            return known
        adjacent = self._adjacency()
        hops, paths = [-1] * len(adjacent), [0] * len(adjacent)
        start = self._bits[frame].bit_length() - 1
        hops[start], paths[start] = 0, 1
        level, seen, depth = [start], 1 << start, 0
        while level:
            depth += 1
            following: list[int] = []
            for at in level:
                rest = adjacent[at]
                while rest:
                    low = rest & -rest
                    v = low.bit_length() - 1
                    rest ^= low
                    if not seen & low:
                        seen |= low
                        hops[v] = depth
                        following.append(v)
                    if hops[v] == depth:
                        paths[v] += paths[at]
            level = following
        known = self._counts[frame] = (hops, paths)
        return known

    def _hops_avoiding(self, start_bit: int, avoid: int) -> dict[int, int]:
        """Hops to each frame (by bit) reached from the frame of ``start_bit`` without
        entering ``avoid`` (bits; :meth:`_levels`)."""
        hops = {}
        for depth, frontier in self._levels(start_bit, avoid):
            while frontier:
                low = frontier & -frontier
                hops[low] = depth
                frontier ^= low
        return hops

    def _levels(self, start_bit: int, avoid: int) -> Iterator[tuple[int, int]]:
        """The frames (bits) first reached at each number of hops from the frame of
        ``start_bit``, 0 first, without entering ``avoid`` (bits): breadth-first on the
        neighbours' bits (:attr:`_adjacent`), ``O(frames)`` word operations in all. The
        frames' bits are taken before the search (:meth:`_adjacency` covers them)."""
        adjacent = self._adjacency()
        seen = start_bit | avoid
        frontier, depth = start_bit, 0
        while frontier:
            yield depth, frontier
            reached, rest = 0, frontier
            while rest:
                low = rest & -rest
                reached |= adjacent[low.bit_length() - 1]
                rest ^= low
            depth += 1
            frontier = reached & ~seen
            seen |= frontier

    def viable_chain(self, template: Template) -> Viable:
        """The occurrences of a chain template worth applying, as a test of partial ones for
        the matcher (which drops the others before it binds the remaining links): the chain is
        wanted (:meth:`_wanted`: decided as soon as the output's type and source, a point
        being carried only into a query frame, or both its frames are bound) and, for a
        dynamic query, once every link is bound, it can lie on a way of the query
        (:meth:`_on_a_way`)."""
        output = template.outputs[0]
        var = output.type[1:] if output.type.startswith("$") else None
        links = len(template.inputs)
        edges = self.index.edges

        def viable(
            roles: Mapping[str, str], types: Mapping[str, str], bound: Mapping[int, str]
        ) -> bool:
            edge_type = types.get(var) if var else output.type
            source = roles.get(output.source)
            if edge_type is None or source is None or self.goal is None:
                return True
            target = roles.get(output.target)
            if target is None:
                return edge_type != "3D" or source in self.goal
            if not self._wanted(template, edge_type, source, target):
                return False
            if len(bound) < links:
                return True
            chained = [edges[bound[i]] for i in range(links)]
            if self.neighbours and not self._on_a_way(source, target, chained):
                return False
            return not self._chain_outclassed(template, source, target, edge_type, chained)

        return viable

    def last_link(self, template: Template) -> LastLink | None:
        """For a dynamic query, :meth:`viable_chain`'s test of a completed chain, asked of the
        edge that would bind its last link before it is bound, the plain hops from the query
        frames to the chain's ends (within the span and slack less the links' hops) first:
        in two rooms with four bodies and three trackers each, 1,535 of 1,897 completed
        chains failed that after binding; in a room with seven redundant trackers, 1,190 of
        the 1,378 edges that passed it were rejected after binding by the rest of the test
        (:meth:`_wanted`, :meth:`_on_a_way`, :meth:`_chain_outclassed`). It passes exactly
        the chains :meth:`viable_chain` passes, and the matcher does not ask that again of an
        occurrence completed through it, so the matches are the same and a rejected edge is
        never bound. ``O(links)`` per last input, ``O(links)`` per edge tried there besides
        the memoised way tests."""
        if not self.neighbours or self.goal is None:
            return None
        output = template.outputs[0]
        source, target = output.source, output.target
        var = output.type[1:] if output.type.startswith("$") else None
        links = len(template.inputs)
        edges = self.index.edges
        bits = self._frame_bits
        from_start, from_end = self._goal_hops or self._hops_to_goal()
        far = len(self.neighbours) + 1
        budget = self.span + self.detour

        def at(
            spec: InputSpec,
            roles: Mapping[str, str],
            types: Mapping[str, str],
            bound: Mapping[int, str],
        ) -> LastTest | None:
            x, y = roles.get(source), roles.get(target)
            x_end = None if x is not None else _end_of(spec, source)
            y_end = None if y is not None else _end_of(spec, target)
            edge_type = types.get(var) if var else output.type
            if (
                (x is None and x_end is None)
                or (y is None and y_end is None)
                or (edge_type is None and spec.type_var != var)
            ):
                return None
            left = budget
            for e in bound.values():
                left -= edges[e].hops
            inside = -1  # the frames of the bound links as bits, found for the first edge

            def fits(edge: EdgeRecord) -> bool:
                nonlocal inside
                a = x if x_end is None else x_end(edge)
                b = y if y_end is None else y_end(edge)
                limit = left - edge.hops
                forward = from_start.get(a, far) + from_end.get(b, far) <= limit
                backward = from_start.get(b, far) + from_end.get(a, far) <= limit
                if not (forward or backward):
                    return False
                kind = edge.type if edge_type is None else edge_type
                if not self._wanted(template, kind, a, b):
                    return False
                if inside < 0:
                    inside = 0
                    for e in bound.values():
                        inside |= bits(edges[e])
                if not self._way_around(a, b, inside | bits(edge), limit, forward, backward):
                    return False
                chained = [edge if i not in bound else edges[bound[i]] for i in range(links)]
                return not self._chain_outclassed(template, a, b, kind, chained)

            narrow = None
            if (x is None) != (y is None) and edge_type != "3D":
                fixed, free_end = (x, y_end) if x is not None else (y, x_end)
                narrow = self._narrowing(template, edge_type, fixed, free_end)
            return LastTest(fits, narrow)

        return at

    def _narrowing(
        self,
        template: Template,
        edge_type: str | None,
        fixed: str,
        free_end: Callable[[EdgeRecord], str],
    ) -> Callable[[Sequence[str]], Sequence[str]] | None:
        """For :meth:`last_link`: the candidates of a chain's last link without the edges
        whose free end (``free_end``: the output role the edge binds) is as far from each query
        frame as the ``fixed`` end (the output role bound already), neither of them a query
        frame: :meth:`_wanted` turns such a chain down, so ``fits`` would reject each; a point
        (3D) is left to ``fits``. In a room with K redundant trackers the trackers' frames are
        all as far from the camera and the marker, and every tracker's edge at the room frame
        was a candidate last link of every other's chain there: 376,657 ``fits`` calls at K
        = 400, 55,857 with this (``docs/performance.md``, "Planner, session 26"). ``O(1)`` a
        candidate in a list comprehension instead of a call."""
        if template.signature != "chain" or not self.either_way or fixed in self.goal:
            return None
        key = (self._class(fixed), edge_type, free_end)
        if key not in self._narrowers:
            self._narrowers[key] = self._narrower(key)
        return self._narrowers[key]

    def _narrower(
        self, key: tuple[tuple[int, int], str | None, Callable[[EdgeRecord], str]]
    ) -> Callable[[Sequence[str]], Sequence[str]] | None:
        """:meth:`_narrowing`'s function for a fixed end's distance class, a type and a free
        end (``key``), made once per plan."""
        fixed_class, edge_type, free_end = key
        same = self._classes().get(fixed_class, ())
        if len(same) < 2:
            return None  # only the fixed end itself
        edges = self.index.edges
        if edge_type is None:  # the type comes with the edge: a point is fits' to judge

            def kept(ids: Sequence[str]) -> list[str]:
                return [
                    e for e in ids if free_end(link := edges[e]) not in same or link.type == "3D"
                ]
        else:

            def kept(ids: Sequence[str]) -> list[str]:
                return [e for e in ids if free_end(edges[e]) not in same]

        return _MemoisedNarrowing(self.index, kept)

    def _class(self, frame: str) -> tuple[int, int]:
        """A frame's hop distances from the query's source and target (:meth:`_wanted`)."""
        near_source, near_target = self.distances
        return near_source[frame], near_target[frame]

    def _classes(self) -> dict[tuple[int, int], frozenset[str]]:
        """The region's frames other than the query's by :meth:`_class`, built once
        (``O(frames)``; the distances are fixed when the search starts)."""
        if self._by_class is None:
            grouped: dict[tuple[int, int], set[str]] = defaultdict(set)
            for frame in self.distances[0]:
                if frame not in self.goal:
                    grouped[self._class(frame)].add(frame)
            self._by_class = {key: frozenset(frames) for key, frames in grouped.items()}
        return self._by_class

    def _on_a_way(self, x: str, y: str, chained: list[EdgeRecord]) -> bool:
        """Whether a chain X->Y of the ``chained`` links (``hops``: the sum of theirs; ``frames``:
        the frames their sources join) can lie on a derivation of a dynamic query S->T: "no
        concatenation that cannot lie on a derivation of the query".

        * S reaches X and Y reaches T (or, read inverted, the other way round) without passing
          a frame inside the chain (a frame of its sources other than X and Y): a derivation
          through such a frame would hold a cycle, and cutting the cycle gives a chain at no
          higher cost on a subset of its sources, which therefore fits wherever the longer one
          does.
        * That way, ``hops(S, X) + hops + hops(Y, T)`` with the first and last hops counted
          around the chain's inside, is no longer than ``detour`` hops beyond a shortest S-T
          path: the slack that bounds the region's frames bounds the ways through them too.

        Plain hop distances (a lower bound of those around the inside) are tried first.
        Only dynamic queries are pruned (:attr:`neighbours` is empty otherwise): a static
        query's time-integrated edges may share dynamic sources with the rest (section 5.1),
        so there a cycle can carry information.
        """
        limit = self.span + self.detour
        inside = 0
        for link in chained:
            limit -= link.hops
            inside |= self._frame_bits(link)
        from_start, from_end = self._goal_hops or self._hops_to_goal()
        far = len(self.neighbours) + 1
        forward = from_start.get(x, far) + from_end.get(y, far) <= limit
        backward = from_start.get(y, far) + from_end.get(x, far) <= limit
        if not (forward or backward):
            return False
        return self._way_around(x, y, inside, limit, forward, backward)

    def _way_around(
        self, x: str, y: str, inside: int, limit: float, forward: bool, backward: bool
    ) -> bool:
        """The second test of :meth:`_on_a_way`, for a chain X->Y whose sources join the
        frames ``inside`` (bits) and whose plain hops fit ``forward`` (S..X, Y..T) or
        ``backward``: the query frames reach its ends without passing a frame inside it,
        within ``limit`` hops. Memoised by ends, inside and limit (:attr:`_ways`)."""
        start, end = self.goal
        bx, by = self._bits[x], self._bits[y]
        inside &= ~(bx | by)
        key = (x, y, inside, limit)
        known = self._ways.get(key)
        if known is None:
            avoiding = self._avoiding
            known = self._ways[key] = (
                forward and avoiding(start, x, inside | by) + avoiding(end, y, inside | bx) <= limit
            ) or (
                backward
                and avoiding(start, y, inside | bx) + avoiding(end, x, inside | by) <= limit
            )
        return known

    def add_measured(self, source: str, target: str, edge_id: str, data: dict) -> None:
        """Index one measured SRG edge."""
        record = measured_record(source, target, edge_id, data)
        self.index.add(record)
        self.by_relation[(source, target, record.type, record.static)].append(edge_id)

    def _outclassed(
        self, key: tuple[str, str, str, bool], cost: float, sources: frozenset[str]
    ) -> bool:
        """The part of the "new or better edge" rule that needs no computation's signature, so
        :meth:`apply` asks it before it builds a record: an edge of relation ``key`` that uses
        more sources than a kept alternative without being cheaper, or that is no cheaper than
        the dearest of ``per_relation`` kept ones, is not added.

        Where a static edge serves wherever a dynamic one does (:attr:`static_serves`), the
        static alternatives of the relation are rivals of a dynamic newcomer too: a dynamic edge
        on more sources than a static one and no cheaper is dominated (everything independent
        of it is independent of the static edge, which has no latency), e.g. a tracker's
        surveyed pose fused with a worse estimate of it through the bodies it tracks.

        A newcomer exactly as dear as the dearest of a full relation is turned down, whatever
        its signature: deciding that tie on signatures too made the relation keep the same
        alternatives in any order, but at 14 % more instructions in a room with seven
        trackers (the later, lesser one retires the earlier and is derived from again;
        ``docs/planner.md``, "Ties")."""
        existing = [self.index.edges[e] for e in self.by_relation[key]]
        limit = cost * (1 + _TIE)
        rivals = existing
        if self.static_serves and not key[3]:
            rivals = existing + [
                self.index.edges[e] for e in self.by_relation.get((*key[:3], True), ())
            ]
        if any(other.cost <= limit and other.sources < sources for other in rivals):
            return True
        return len(existing) >= self.per_relation and cost >= max(e.cost for e in existing)

    def group_outclassed(self, key: tuple, members: Sequence[Match]) -> bool:
        """Whether no space expansion of the correspondence group ``key`` of occurrences
        (:func:`~ubitrack_agent.graph.matcher.group_key`) can add an edge, decided before its
        sets of copies are formed: each relation it would write is full (``per_relation``
        alternatives kept) and a lower bound of the cost of any of its expansions
        (:func:`_space_floor`) is no cheaper than the dearest kept alternative, so
        :meth:`_outclassed` would turn down every output. Exact and lasting: a full relation
        stays full and its dearest alternative only gets cheaper (a newcomer is admitted only
        below it and retires it), so the sets skipped now would be turned down whenever they
        were formed, and the plan is the same. A group that may be expanded in time, or whose
        outputs depend on the copies' frames, is not decided here. The relations a group
        writes are found once (:attr:`_writes`), so a group whose relation is not full costs
        two look-ups; the others ``O(n log n)`` for ``n`` occurrences, each one's costs
        gathered once per run (:attr:`_copy_costs`). :func:`saturate` asks it for groups of
        more than ``EXACT_COPIES`` only: the sets of a smaller group cost about what the bound
        does (in a room with 7 trackers, asking for every group cost 4 % more instructions)."""
        writes = self._writes.get(key)
        if writes is None:
            writes = self._writes[key] = self._written(members[0])
        by_relation, most = self.by_relation, self.per_relation
        for source, target, edge_type, kinds in writes:
            if all(len(by_relation.get((source, target, edge_type, k), ())) < most for k in kinds):
                return False  # the common case: a relation it writes is not full
        if not writes:
            return False
        edges = self.index.edges

        def statics() -> set[bool]:  # a set is static iff each of its copies is
            return {all(edges[e].static for e in m.edges) for m in members}

        dearest = self._dearest(writes, statics)
        if dearest is None or time_expandable(members, self.index):
            return False
        return _space_floor(members, self.index, self._copy_costs) >= dearest

    def _written(self, match: Match) -> tuple[tuple[str, str, str, tuple[bool, ...]], ...]:
        """The relations (source, target, type, possible static flags) of useful types that
        the instances of ``match``'s group write, or ``(_UNDECIDED,)`` where
        :meth:`group_outclassed` does not decide."""
        template = match.template
        corr = template.correspondence
        if corr is None or "space" not in corr.expansions or template.outputs_vary:
            return (_UNDECIDED,)
        roles, types = match.role_map, dict(match.types)
        writes = []
        for spec in template.outputs:
            edge_type = types[spec.type[1:]] if spec.type.startswith("$") else spec.type
            if edge_type in self.useful_types:
                kinds = (False, True) if spec.static == "inherit" else (spec.static,)
                writes.append((roles[spec.source], roles[spec.target], edge_type, kinds))
        return tuple(writes)

    def _chain_outclassed(
        self,
        template: Template,
        source: str,
        target: str,
        edge_type: str,
        chained: list[EdgeRecord],
    ) -> bool:
        """Whether a chain ``source -> target`` of the ``chained`` links (in input order) adds
        nothing: its relation is full and its cost, as :meth:`apply` computes it (rule
        ``sum``), no cheaper than the dearest kept alternative (:meth:`_outclassed`). Exact and
        lasting, as for :meth:`group_outclassed`; asked by :meth:`viable_chain` once every
        link is bound, so the occurrence is not even built. ``O(links + per_relation)``."""
        output = template.outputs[0]
        static = (
            all(link.static for link in chained) if output.static == "inherit" else output.static
        )
        dearest = self._full(source, target, edge_type, static)
        return (
            dearest is not None
            and template.cost.rule == "sum"
            and _summed_cost(template, chained) >= dearest
        )

    def _dearest(
        self,
        writes: Sequence[tuple[str, str, str, tuple[bool, ...]]],
        statics: Callable[[], set[bool]],
    ) -> float:
        """The dearest alternative kept in the relations ``writes`` (:meth:`_written`), each
        full or not written: an output inheriting its static flag may write either relation,
        ``statics()`` says which are possible (asked only where one is not full); ``inf`` if a
        written relation is not full, ``-inf`` if none is written. ``O(outputs *
        per_relation)``."""
        dearest = -math.inf
        for source, target, edge_type, kinds in writes:
            for static in kinds:
                cost = self._full(source, target, edge_type, static)
                if cost is not None:
                    dearest = max(dearest, cost)
                elif len(kinds) == 1 or static in statics():
                    return math.inf
        return dearest

    def _full(self, source: str, target: str, edge_type: str, static: bool) -> float | None:
        """The dearest alternative kept in a full relation (``per_relation`` kept), ``None``
        if the relation is not full."""
        kept = self.by_relation.get((source, target, edge_type, static), ())
        if len(kept) < self.per_relation:
            return None
        edges = self.index.edges
        return max(edges[e].cost for e in kept)

    def _admit(self, record: EdgeRecord) -> bool:
        """The rest of the "new or better edge" rule, for a record not :meth:`_outclassed`:
        reject a re-bracketing of a known computation that comes first (:func:`_comes_first`),
        and retire one the newcomer ties with and comes before (one slot per computation, the
        same whichever bracketing came first). Keep at most ``per_relation`` alternatives per
        relation: a cheaper newcomer (:meth:`_outclassed` turned down one as dear) retires the
        last of a full relation in the order of :func:`_ranked` (by cost, ties by signature;
        edges already derived from it stay)."""
        key = (record.source, record.target, record.type, record.static)
        alternatives = self.by_relation[key]
        existing = [self.index.edges[e] for e in alternatives]
        same = [other for other in existing if other.canon == record.canon]
        if any(_comes_first(other, record) for other in same):
            return False
        for other in same:
            if other.cost <= record.cost * (1 + _TIE):  # a tie the newcomer wins
                alternatives.remove(other.id)
                self.index.retire(other.id)
                existing.remove(other)
        if len(existing) >= self.per_relation:
            worst = max(existing, key=_ranked)
            alternatives.remove(worst.id)
            self.index.retire(worst.id)
        return True

    def _wanted(self, template: Template, edge_type: str, source: str, target: str) -> bool:
        """Which chains (templates of ``signature: chain``, concatenation) serve the query
        ``goal`` (section 5.1, "when to add new edges").

        Points (3D) are carried only into the query's frames: a point-based pose estimation on
        points carried into another frame X equals the one on the points' own frame followed by
        the same concatenation. Chains (6D) must start or end at a query frame or join frames at
        different distances from a query frame (hop distances along 6D edges,
        :func:`_chain_distances`): a chain between frames as far from each query frame as each
        other runs across every way between the two. Both directions are kept: a chain against
        the query's direction feeds a derivation that runs the other way round and is inverted
        once at its end, which can cost less than inverting every link before (in a room with
        eight trackers, the fusion of the trackers' ways room -> head inverted once is five
        inversions, 0.05, cheaper than the fusion of the ways head -> room). The rule is the
        same for the query and its inverse, so one saturation serves both (:func:`_plan_parts`)."""
        if template.signature != "chain" or self.goal is None:
            return True
        if edge_type == "3D":
            return source in self.goal
        if source in self.goal or target in self.goal:
            return True
        if not self.either_way:
            near_source, near_target = self.distances
            return (
                near_source[source] < near_source[target]
                or near_target[source] > near_target[target]
            )
        return self._class(source) != self._class(target)  # the class :meth:`_narrowing` skips

    def apply(self, instance: Instance) -> list[str]:
        """Apply ``instance``: add its admissible outputs, record the step, return new edge ids.
        An output no better than what its relation holds (:meth:`_outclassed`, most of those
        rejected) is turned down before its record is built."""
        records = self.index.edges
        inputs = [records[e] for _, ids in instance.inputs for e in ids]
        quality = _propagated(instance, inputs, records)
        step_id = f"{self.prefix}s{len(self.steps) + 1}"
        template = instance.template
        sources = frozenset().union(*(e.sources for e in inputs))
        # a new frame is defined by the one calibration introducing it: the frame counts as a
        # source, so no derivation combines two introductions (two tip calibrations may have
        # calibrated different points)
        if self.index.new_frames:
            sources |= {
                f"introduced:{frame}"
                for _, source, target, *_ in instance.outputs
                for frame in (source, target)
                if frame in self.index.new_frames
            }
        providers = frozenset().union(*(e.providers for e in inputs))
        used = frozenset().union(*(e.steps for e in inputs))
        cost = edge_cost(quality, len(providers), len(used) + (step_id not in used))
        steps = None  # with this step: made for the first output kept
        outputs, added = [], []
        for name, source, target, edge_type, static, mode in instance.outputs:
            edge_id = None
            # a time expansion yields rigid relations: those not measured already are added;
            # hand-eye's measured R->O is listed, not added, and so is a relation of an
            # introduced frame the query leaves non-rigid (the pivot of a tip calibration
            # queried from the marker)
            kept = instance.expansion != "time" or (
                self.index.is_rigid(source, target)
                and not self.index.is_measured_rigid(source, target)
            )
            key = (source, target, edge_type, static)
            if (
                edge_type in self.useful_types
                and kept
                and self._wanted(template, edge_type, source, target)
                and not self._outclassed(key, cost, sources)
            ):
                hops = (
                    sum(e.hops for e in inputs)
                    if template.signature != "step"
                    else (max(1, self._distance(source, target)) if self.neighbours else 1)
                )
                if steps is None:
                    steps = frozenset({step_id}).union(*(e.steps for e in inputs))
                record = _derived(
                    template,
                    instance.expansion,
                    inputs,
                    step_id,
                    (name, source, target, edge_type, static, mode),
                    quality,
                    (sources, providers, steps),
                    cost,
                    hops,
                    _signature(template, instance.expansion, name, instance.inputs, records),
                )
                if self._admit(record):
                    self.index.add(record)
                    self.by_relation[key].append(record.id)
                    edge_id = record.id
                    added.append(record.id)
            outputs.append((name, source, target, edge_type, edge_id))
        if added:
            self.steps[step_id] = Step(
                step_id, template, instance.expansion, instance.inputs, tuple(outputs)
            )
        return added


_UNDECIDED = ("", "", "", ())
"""What :meth:`Workspace._written` gives a group :meth:`Workspace.group_outclassed` does not
decide: no relation, so no look-up finds it full."""


@dataclass(frozen=True)
class _CopyCost:
    """What a copy adds to the cost of a space expansion, read off its correspondence edges:
    their summed variance and summed inverse variance, their largest latency, their sensors
    and their steps."""

    variance: float
    inverse: float
    latency: float
    providers: frozenset[str]
    steps: frozenset[str]


def _copy_cost(
    match: Match, index: EdgeIndex, memo: dict[tuple[str, tuple[str, ...]], _CopyCost]
) -> _CopyCost:
    """The :class:`_CopyCost` of ``match``, memoised by template name and input edges."""
    key = (match.template.name, match.edges)
    known = memo.get(key)
    if known is None:
        corr = match.template.correspondence
        assert corr is not None
        copied = match.template.in_correspondence
        records = [index.edges[e] for c, e in zip(copied, match.edges, strict=True) if c]
        known = memo[key] = _CopyCost(
            sum(r.quality.variance for r in records),
            sum(1.0 / max(r.quality.variance, VARIANCE_FLOOR) for r in records),
            max(r.quality.latency for r in records),
            frozenset().union(*(r.providers for r in records)),
            frozenset().union(*(r.steps for r in records)),
        )
    return known


def _space_floor(
    members: Sequence[Match],
    index: EdgeIndex,
    memo: dict[tuple[str, tuple[str, ...]], _CopyCost],
) -> float:
    """A lower bound of the cost of every space expansion of ``members`` (one correspondence
    group), from the costs of its copies alone, for :meth:`Workspace.group_outclassed`.

    A set holds ``m`` copies, ``lo <= m <= most``: the multiplicity's least, and the most
    that the group's frames allow (copies differ in every expanded role). Each term of the
    cost is bounded on its own:

    * variance (:func:`propagate`): ``pooled`` is at least the inputs outside the
      correspondence plus the mean of the ``m`` copies' variances scaled by ``lo / m`` (the
      shared part only adds), so at least ``fixed + lo * S_m / m**2`` with ``S_m`` the sum of
      the ``m`` least variances; ``fusion`` is at least ``1 / (fixed's inverses + the m
      greatest inverses)``; times the template's gain;
    * latency: the largest input's, at least the ``lo``-th least of the copies' (and the
      fixed inputs'), plus the template's;
    * sensors and steps: at least the ``lo``-th least of one copy's with the fixed inputs'
      (steps plus the instance's own); for ``independent`` copies, whose sources and hence
      steps are disjoint, the sum of the ``m`` least counts of steps.

    The bound is the least over ``m`` of these terms' costs, less a relative ``_TIE`` for
    rounding. Another rule, or no ``m`` at all: no bound below infinity but the exact one.
    ``O(n log n)`` for ``n`` copies."""
    template = members[0].template
    corr = template.correspondence
    assert corr is not None
    spec = template.cost
    copies = [_copy_cost(m, index, memo) for m in members]
    copied = template.in_correspondence
    fixed = [index.edges[e] for c, e in zip(copied, members[0].edges, strict=True) if not c]
    lo = corr.multiplicity.lo
    most = len(members) if corr.multiplicity.hi is None else min(len(members), corr.multiplicity.hi)
    for role in corr.expand_roles:
        most = min(most, len({m.role_map[role] for m in members}))
    if spec.rule not in ("pooled", "fusion"):
        return -math.inf
    if most < lo:
        return math.inf
    fixed_providers = frozenset().union(*(r.providers for r in fixed))
    fixed_steps = frozenset().union(*(r.steps for r in fixed))
    latency = max([r.quality.latency for r in fixed] + [sorted(c.latency for c in copies)[lo - 1]])
    providers = sorted(len(fixed_providers | c.providers) for c in copies)[lo - 1]
    if corr.independent:  # disjoint sources, so disjoint steps: each copy adds all of its own
        first, adds = 0, sorted(len(c.steps) for c in copies)
    else:  # a step only copies of the same expanded frames use is theirs alone in a set
        kinds = [
            tuple(m.role_map[r] for r in corr.expand_roles) or i for i, m in enumerate(members)
        ]
        users: dict[str, set] = defaultdict(set)
        for kind, c in zip(kinds, copies, strict=True):
            for step in c.steps:
                users[step].add(kind)
        first = min(len(c.steps) for c in copies)
        adds = [0, *sorted(sum(len(users[step]) == 1 for step in c.steps) for c in copies)]
    steps_lo = sorted(len(fixed_steps | c.steps) for c in copies)[lo - 1]
    rest = latency / LATENCY_REF + (spec.latency / LATENCY_REF) + SENSOR_WEIGHT * providers
    if spec.rule == "pooled":
        fixed_variance = sum(r.quality.variance for r in fixed)
        variances = sorted(c.variance for c in copies)
    else:
        fixed_inverse = sum(1.0 / max(r.quality.variance, VARIANCE_FLOOR) for r in fixed)
        inverses = sorted((c.inverse for c in copies), reverse=True)
    least = math.inf
    summed, steps_summed = 0.0, first
    for m in range(1, most + 1):
        if spec.rule == "pooled":
            summed += variances[m - 1]
            variance = fixed_variance + lo * summed / m**2
        else:
            summed += inverses[m - 1]
            variance = 1.0 / (fixed_inverse + summed)
        steps_summed += adds[m - 1]
        if m < lo:
            continue
        steps = max(steps_lo, len(fixed_steps), steps_summed)
        cost = variance * spec.gain / SIGMA_REF**2 + rest + STEP_WEIGHT * (steps + 1)
        least = min(least, cost)
    return least * (1 - _TIE)


def _source(edge: EdgeRecord) -> str:
    return edge.source


def _target(edge: EdgeRecord) -> str:
    return edge.target


def _end_of(spec: InputSpec, role: str) -> Callable[[EdgeRecord], str] | None:
    """Which end of an edge bound as input ``spec`` binds ``role`` (``None``: neither)."""
    if spec.source == role:
        return _source
    return _target if spec.target == role else None


def measured_record(source: str, target: str, edge_id: str, data: Mapping) -> EdgeRecord:
    """The record of a measured SRG edge ``source -> target`` (its key and attributes)."""
    providers = frozenset({data["provider"]})
    return EdgeRecord(
        id=edge_id,
        source=source,
        target=target,
        type=data["type"],
        static=data["static"],
        mode=data["mode"],
        measured=True,
        provider=data["provider"],
        quality=data["quality"],
        sources=frozenset({edge_id}),
        frames=frozenset((source, target)),
        cost=edge_cost(data["quality"], len(providers), 0),
        canon=f"m:{edge_id}",
        leaves=(f"m:{edge_id}",),
        providers=providers,
        signature=("", edge_id),
    )


def _derived(
    template: Template,
    expansion: str,
    inputs: list[EdgeRecord],
    step_id: str,
    output: tuple[str, str, str, str, bool, str],
    quality: Quality,
    uses: tuple[frozenset[str], frozenset[str], frozenset[str]],
    cost: float,
    hops: int,
    signature: tuple,
) -> EdgeRecord:
    """The record of ``output`` (name, source, target, type, static, mode) of the step
    ``step_id`` that applies ``template`` to ``inputs``; ``uses`` are its sources, providers and
    steps; ``signature`` the derivation's (:func:`_signature`). Its computation's canonical
    signature (``canon``): an inverse is its input, a chain the sorted computations it chains
    (``leaves``, any bracketing), any other step its own on its inputs and the output's frames
    (:attr:`Template.signature`)."""
    name, source, target, edge_type, static, mode = output
    if template.signature == "inverse":
        canon, leaves = inputs[0].canon, inputs[0].leaves
    elif template.signature == "chain":
        leaves = tuple(sorted(leaf for e in inputs for leaf in e.leaves))
        canon = f"cat({','.join(leaves)})"
    else:
        computed = ",".join(sorted(e.canon for e in inputs))
        canon = f"{template.pattern}/{expansion}[{computed}]{'-'.join(sorted((source, target)))}"
        leaves = (canon,)
    sources, providers, steps = uses
    return EdgeRecord(
        id=f"{source}->{target}:{edge_type}@{step_id}.{name}",
        source=source,
        target=target,
        type=edge_type,
        static=static,
        mode=mode,
        measured=False,
        provider=template.service,
        quality=quality,
        sources=sources,
        frames=frozenset().union(*(e.frames for e in inputs)),
        cost=cost,
        canon=canon,
        leaves=leaves,
        pattern=template.pattern,
        step=step_id,
        time_integrated=expansion == "time",
        steps=steps,
        providers=providers,
        hops=hops,
        signature=signature,
    )


def _signature(
    template: Template,
    expansion: str,
    output: str,
    inputs: Sequence[tuple[str, Sequence[str]]],
    records: Mapping[str, EdgeRecord],
) -> tuple:
    """What a derivation computes, whatever order its steps were made in
    (:attr:`EdgeRecord.signature`): the template, the expansion, the output's name and the
    signatures of the inputs in the template's order, the copies of a space expansion sorted
    (their order in the instance is the order the matcher found them in, and changes nothing
    computed). ``inputs`` are the instance's edge ids by input name, ``records`` their records.
    ``O(inputs log copies)``: the inputs' signatures are shared, not copied."""
    corr = template.correspondence
    if corr is None or expansion != "space":
        fixed = tuple(tuple(records[e].signature for e in ids) for _, ids in inputs)
        return (template.name, expansion, output, fixed, ())
    fixed = tuple(
        tuple(records[e].signature for e in ids) for n, ids in inputs if n not in corr.edges
    )
    rows = [ids for n, ids in inputs if n in corr.edges]
    copies = sorted(tuple(records[e].signature for e in copy) for copy in zip(*rows, strict=True))
    return (template.name, expansion, output, fixed, tuple(copies))


def saturate(
    srg: nx.MultiDiGraph,
    templates: Sequence[Template],
    frames: Iterable[str],
    wanted: str,
    rigid: Iterable[tuple[str, str]] = (),
    per_relation: int = DEFAULT_PER_RELATION,
    goal: tuple[str, str] | None = None,
    new_frames: Iterable[str] = (),
    slack: int = DEFAULT_SLACK,
    prefix: str = "",
    prune: bool = True,
    copies: CopySets = copy_sets,
    either_way: bool = True,
) -> Workspace:
    """Apply all templates to the SRG restricted to ``frames`` until nothing new is inferred.

    Only edges of types that can contribute to a ``wanted`` edge are inferred, and time-only
    patterns (calibrations) only run when some rigid relation is not measured. With a ``goal``
    (the query's source and target), chains (concatenations) are restricted as
    :meth:`Workspace._wanted` explains (``either_way``). ``prune`` and ``copies`` are the
    search's own (the test oracle turns them off). ``rigid`` adds frame pairs known to be rigid
    besides those joined by static edges. ``new_frames`` are frames without edges that patterns
    with introduced roles may bind (:func:`introducible_frames`); without them those patterns do
    not run. Each round only looks for occurrences that use an edge inferred in the previous round.
    """
    frames = set(frames)
    ws = Workspace(
        per_relation=per_relation,
        useful_types=useful_types(templates, wanted),
        goal=goal,
        detour=slack,
        prefix=prefix,
        either_way=either_way,
    )
    ws.index.new_frames = tuple(new_frames)
    if goal is not None:
        ws.distances = _chain_distances(srg, frames, goal)
    for source in sorted(frames):  # a canonical order: the plan must not depend on announcement
        for target in sorted(frames.intersection(srg.succ[source])):
            for key, data in sorted(srg.succ[source][target].items()):
                ws.add_measured(source, target, key, data)
    rigid = [(a, b) for a, b in rigid if not ws.index.is_measured_rigid(a, b)]
    if prune and goal is not None and not rigid:  # no time integration: no chain on a cycle
        ws.neighbours = {f: frames.intersection((*srg.succ[f], *srg.pred[f])) for f in frames}
        ws.span = _span(srg, frames, goal, wanted, ws._around)
    for a, b in rigid:
        ws.index.add_rigid(a, b)
    # a time expansion's edges are kept only for a rigid relation not measured (apply)
    ws.index.space_only = prune and not rigid and not ws.index.new_frames
    # a time-only pattern yields static edges, wanted only for rigid relations not yet measured;
    # a pattern introducing a frame needs a frame to introduce
    templates = [
        t
        for t in templates
        if (rigid or not t.time_only) and (ws.index.new_frames or not t.introduced)
    ]
    # a dynamic query takes static edges too; where no pattern asks for a dynamic input, a
    # static edge serves wherever a dynamic one of its relation does (Workspace._admit)
    ws.static_serves = (
        prune
        and goal is not None
        and not rigid
        and all(spec.static is not False for t in templates for spec in t.inputs)
    )
    viable = {t.name: ws.viable_chain(t) for t in templates if t.signature == "chain"}
    last = {t.name: ws.last_link(t) for t in templates if t.signature == "chain"}
    groups: dict[tuple, dict[tuple[str, ...], Match]] = {}
    applied: set[tuple] = set()
    new = list(ws.index.edges)
    while new:
        touched: dict[tuple, None] = {}
        for template in templates:
            chain = prune and template.signature == "chain"
            found = (
                find_matches(template, ws.index, new, viable[template.name], last[template.name])
                if chain
                else find_matches(template, ws.index, new)
            )
            for match in found:
                key = (template.name, group_key(match))
                members = groups.setdefault(key, {})
                if match.edges not in members:
                    members[match.edges] = match
                    touched[key] = None
        new = []
        for key in touched:
            retired = ws.index.retired
            members = [m for m in groups[key].values() if retired.isdisjoint(m.edges)]
            if not members or (
                prune and len(members) > EXACT_COPIES and ws.group_outclassed(key, members)
            ):
                continue
            for instance in expand_group(members, ws.index, copies, applied):
                if instance.key not in applied:
                    applied.add(instance.key)
                    new.extend(ws.apply(instance))
    return ws


def _solution(ws: Workspace, edge: EdgeRecord) -> Solution:
    """The solution deriving ``edge``: its steps with inputs before the steps that use them."""
    order: list[Step] = []
    records: dict[str, EdgeRecord] = {edge.id: edge}
    _visit(ws, edge, order, records)
    return Solution(edge, tuple(order), records)


def _visit(
    ws: Workspace, record: EdgeRecord, order: list[Step], records: dict[str, EdgeRecord]
) -> None:
    """Depth first from ``record`` (:func:`_solution`): the steps deriving it appended to
    ``order`` after those deriving their inputs, every edge they read or write to
    ``records``."""
    records[record.id] = record
    if record.step is None or any(s.id == record.step for s in order):
        return
    step = ws.steps[record.step]
    for _, ids in step.inputs:
        for edge_id in ids:
            _visit(ws, ws.index.edges[edge_id], order, records)
    for *_, edge_id in step.outputs:
        if edge_id is not None:
            records[edge_id] = ws.index.edges[edge_id]
    order.append(step)


def solutions(ws: Workspace, query: Query) -> list[Solution]:
    """Every distinct derivation of ``query`` in ``ws``, cheapest first.

    A dynamic query accepts static edges too (a static edge is valid at every time); derivations
    that differ only in bracketing or inversion order are listed once.
    """
    found: dict[str, EdgeRecord] = {}
    for static in (True, False) if not query.static else (True,):
        key = (query.source, query.target, query.type, static)
        for edge_id in ws.by_relation.get(key, ()):
            record = ws.index.edges[edge_id]
            best = found.get(record.canon)
            if best is None or _ranked(record) < _ranked(best):
                found[record.canon] = record
    return [_solution(ws, edge) for edge in sorted(found.values(), key=_ranked)]


def _ranked(edge: EdgeRecord) -> tuple[float, int, tuple, str]:
    """The order of derivations: cheapest first, then fewest steps, then by signature (what
    the derivation computes, :attr:`EdgeRecord.signature`, independent of the order in which
    steps were made), then by id (two records of one signature are one computation)."""
    return (edge.cost, len(edge.steps), edge.signature, edge.id)


def _comes_first(a: EdgeRecord, b: EdgeRecord) -> bool:
    """``a`` ranks before ``b`` where their costs may differ by rounding only (a relative
    ``_TIE``: the same computation bracketed otherwise sums its variances in another order):
    cheaper beyond it, else the lesser signature. Either of two records comes first, whichever
    was made first."""
    if a.cost < b.cost * (1 - _TIE) or a.cost > b.cost * (1 + _TIE):
        return a.cost < b.cost
    return a.signature <= b.signature


def with_solution(srg: nx.MultiDiGraph, solution: Solution) -> nx.MultiDiGraph:
    """A copy of ``srg`` with the edges ``solution`` infers added as inferred SRG edges
    (``measured`` false, ``provider`` the service, ``derivation`` the step id)."""
    graph = srg.copy()
    graph.graph["edge_index"] = dict(edge_ids(srg))
    for record in solution.records.values():
        if record.measured:
            continue
        attrs = EdgeAttrs(
            type=record.type,
            static=record.static,
            mode=record.mode,
            measured=False,
            provider=record.provider,
            quality=record.quality,
            sources=record.sources,
            derivation=record.step,
        )
        graph.add_edge(record.source, record.target, key=record.id, **attrs.as_data())
        graph.graph["edge_index"][record.id] = (record.source, record.target)
    return graph


class PartCache:
    """The derivations of parts (:func:`_plan_parts`) shared across queries and plans: a part
    is saturated once for as long as its shape (:func:`_part_shape`: its frames' edges up to
    names, its ends, the templates) is the same (memoised sub-derivations: every query through
    a room reuses the room's part, an event elsewhere in the building leaves it valid, and a
    room equipped as another takes that room's derivations, renamed). At most ``size`` parts,
    the least recently used dropped first. Not thread-safe: one planner thread uses it."""

    def __init__(self, size: int = 4096) -> None:
        self.size = size
        self.hits = 0
        self.misses = 0
        self._parts: OrderedDict[tuple, PartPlan] = OrderedDict()

    def get(self, key: tuple) -> PartPlan | None:
        found = self._parts.get(key)
        if found is None:
            self.misses += 1
            return None
        self.hits += 1
        self._parts.move_to_end(key)
        return found

    def put(self, key: tuple, found: PartPlan) -> None:
        self._parts[key] = found
        self._parts.move_to_end(key)
        while len(self._parts) > self.size:
            self._parts.popitem(last=False)


@dataclass(frozen=True)
class PartNames:
    """The names a part's shape leaves out, each kind sorted: its frames, its edges' keys and
    their providers; and the prefix of the ids of the steps planned for it."""

    frames: tuple[str, ...]
    edges: tuple[str, ...]
    providers: tuple[str, ...]
    prefix: str


@dataclass(frozen=True)
class PartPlan:
    """A part's derivations between its ends, each way round (keyed by the ends' ranks among
    its frames), as planned for the part named ``names``."""

    names: PartNames
    found: Mapping[tuple[int, int], list[Solution]]


def _part_shape(
    srg: nx.MultiDiGraph,
    templates: Sequence[Template],
    part: set[str],
    ends: tuple[str, str],
    slack: int,
    per_relation: int,
) -> tuple[tuple, PartNames]:
    """What a part's derivations depend on, up to names, and its names.

    The shape holds its edges with every attribute the planner reads, each name replaced by its
    rank among the part's names of its kind (frames, edge keys, providers), the ranks of its
    two ends (either way round: one saturation serves both, :meth:`Workspace._wanted`), the
    templates (by name and object: templates loaded anew are another catalogue) and the bounds.
    Two parts of one shape are one part under a renaming that keeps the order of every kind
    of name, so the planner, which breaks ties by names, takes the same steps for both (rooms
    equipped alike, their frames and sensors named alike). ``O(E log E)`` for the part's ``E``
    edges. The steps' prefix is a digest of the part with its names."""
    frames = sorted(part)
    edges = sorted(
        (u, v, k, d["type"], d["static"], d["mode"], d["provider"], d["quality"])
        for u, v, k, d in _edges_within(srg, part)
    )
    keys = sorted(e[2] for e in edges)
    providers = sorted({e[6] for e in edges})
    rank = {name: i for kind in (frames, keys, providers) for i, name in enumerate(kind)}
    shape = sorted((rank[u], rank[v], rank[k], *rest, rank[p], q) for u, v, k, *rest, p, q in edges)
    catalogue = (tuple(t.name for t in templates), tuple(map(id, templates)))
    key = (tuple(sorted(rank[e] for e in ends)), tuple(shape), catalogue, slack, per_relation)
    digest = repr((sorted(ends), edges, catalogue[0])).encode()
    prefix = hashlib.sha1(digest).hexdigest()[:10] + "."
    return key, PartNames(tuple(frames), tuple(keys), tuple(providers), prefix)


def _renamed(
    found: list[Solution], srg: nx.MultiDiGraph, old: PartNames, new: PartNames
) -> list[Solution]:
    """``found``, planned for the part named ``old``, for the part of the same shape named
    ``new``: every name mapped to the one of its rank, the steps' ids to the new prefix, and
    each inferred edge's record made again from its renamed inputs in data-flow order (so its
    signature and id are those a plan of the new part gives). ``O(records + steps)``."""
    frame = dict(zip(old.frames, new.frames, strict=True))
    key = dict(zip(old.edges, new.edges, strict=True))
    provider = dict(zip(old.providers, new.providers, strict=True))
    records: dict[str, EdgeRecord] = {}  # by the old id
    steps: dict[str, Step] = {}  # by the old id

    def step_id(old_id: str) -> str:
        return new.prefix + old_id.removeprefix(old.prefix)

    def measured(record: EdgeRecord) -> EdgeRecord:
        u, v, k = frame[record.source], frame[record.target], key[record.id]
        return measured_record(u, v, k, srg.edges[u, v, k])

    def rename(step: Step, made: Mapping[str, EdgeRecord]) -> Step:
        inputs = tuple((n, tuple(records[e].id for e in ids)) for n, ids in step.inputs)
        given = [records[e] for _, ids in step.inputs for e in ids]
        outputs = []
        for name, source, target, edge_type, edge_id in step.outputs:
            if edge_id is not None:
                was = made[edge_id]
                records[edge_id] = _derived(
                    step.template,
                    step.expansion,
                    given,
                    step_id(step.id),
                    (name, frame[source], frame[target], edge_type, was.static, was.mode),
                    was.quality,
                    (
                        frozenset(key[s] for s in was.sources),
                        frozenset(provider[p] for p in was.providers),
                        frozenset(map(step_id, was.steps)),
                    ),
                    was.cost,
                    was.hops,
                    _signature(step.template, step.expansion, name, step.inputs, records),
                )
                edge_id = records[edge_id].id
            outputs.append((name, frame[source], frame[target], edge_type, edge_id))
        return Step(step_id(step.id), step.template, step.expansion, inputs, tuple(outputs))

    renamed = []
    for solution in found:
        for record in solution.records.values():
            if record.measured and record.id not in records:
                records[record.id] = measured(record)
        for step in solution.steps:
            if step.id not in steps:
                steps[step.id] = rename(step, solution.records)
        renamed.append(
            Solution(
                records[solution.edge.id],
                tuple(steps[step.id] for step in solution.steps),
                {records[e].id: records[e] for e in solution.records},
            )
        )
    return sorted(renamed, key=lambda s: _ranked(s.edge))


def _plan_parts(
    srg: nx.MultiDiGraph,
    templates: Sequence[Template],
    query: Query,
    parts: Sequence[tuple[str, str, set[str]]],
    slack: int,
    per_relation: int,
    cache: PartCache | None,
    chain: Template,
) -> list[Solution]:
    """Solutions of a dynamic 6D query whose region has cut frames (:mod:`segments`): each
    part planned on its own (or taken from ``cache``), then the parts' derivations chained by
    the template ``chain`` (a catalogue without one plans the region whole).

    The best solution chains every part's best derivation; the others change one part's
    derivation to its next best, cheapest first, at most ``per_relation`` in all. The links of
    the parts' chains are bracketed anew as one chain, joining each time the neighbours whose
    join has the least latency, so that the slowest links are composed last (the cost model
    charges each concatenation's latency on the way of the data). ``O(parts)`` saturations of
    one part's region each.
    """
    joined = Workspace(per_relation=sys.maxsize, prefix="j.")
    alternatives: list[list[EdgeRecord]] = []
    cache = PartCache() if cache is None else cache  # parts alike within one plan too
    for a, b, part in parts:
        key, names = _part_shape(srg, templates, part, (a, b), slack, per_relation)
        rank = {frame: i for i, frame in enumerate(names.frames)}
        planned = cache.get(key)
        if planned is None:
            ws = saturate(
                srg, templates, part, "6D", (), per_relation, (a, b), (), slack, names.prefix
            )
            planned = PartPlan(
                names,
                {(rank[x], rank[y]): solutions(ws, Query(x, y, "6D")) for x, y in ((a, b), (b, a))},
            )
            cache.put(key, planned)
        found = planned.found[(rank[a], rank[b])]
        if planned.names != names:
            found = _renamed(found, srg, planned.names, names)
        if not found:
            raise NoSolutionError(
                f"no derivation of 6D {query.source}->{query.target}: every way passes "
                f"{b if a == query.source else a} and no combination of patterns yields "
                f"6D {a}->{b} (frames considered: {', '.join(sorted(part))})"
            )
        for solution in found:
            joined.index.edges.update(solution.records)
            joined.steps.update((step.id, step) for step in solution.steps)
        alternatives.append([s.edge for s in found])
    best = [options[0] for options in alternatives]
    variants = (
        [*best[:i], option, *best[i + 1 :]]
        for i, options in enumerate(alternatives)
        for option in options[1:]
    )
    picks = [best, *sorted(variants, key=lambda links: sum(e.cost for e in links))]
    made: dict[tuple[str, str], EdgeRecord] = {}
    for parts_links in picks[:per_relation]:
        links = [link for edge in parts_links for link in _links(joined, chain, edge)]
        _join(joined, chain, links, made)
    return solutions(joined, query)


def _links(ws: Workspace, chain: Template, edge: EdgeRecord) -> list[EdgeRecord]:
    """The links of ``edge`` if a chain made it (in order, through chains of chains), else
    ``[edge]``: a part's chain is bracketed again with its neighbours' links."""
    if edge.pattern != chain.pattern or edge.step is None:
        return [edge]
    step = ws.steps[edge.step]
    ids = [edge_id for _, group in step.inputs for edge_id in group]
    return [link for edge_id in ids for link in _links(ws, chain, ws.index.edges[edge_id])]


def _chain_types(template: Template) -> set[str]:
    """The types a chain template's output may take."""
    out = template.outputs[0].type
    return set(template.type_vars[out[1:]]) if out.startswith("$") else {out}


def _join(
    ws: Workspace,
    chain: Template,
    links: Sequence[EdgeRecord],
    made: dict[tuple[str, str], EdgeRecord],
) -> EdgeRecord | None:
    """The chain of ``links`` (consecutive 6D edges with disjoint sources) applied in ``ws``,
    joining first the neighbours whose join has the least latency; joins already ``made`` are
    reused. ``None`` if ``ws`` admits no such chain (one as good is there already)."""
    items = list(links)
    while len(items) > 1:
        i = min(
            range(len(items) - 1),
            key=lambda k: (max(items[k].quality.latency, items[k + 1].quality.latency), k),
        )
        a, b = items[i], items[i + 1]
        record = made.get((a.id, b.id))
        if record is None:
            roles = {chain.inputs[0].source: a.source, chain.inputs[0].target: a.target}
            roles[chain.inputs[1].target] = b.target
            var = chain.outputs[0].type[1:] if chain.outputs[0].type.startswith("$") else None
            match = Match(
                chain,
                (a.id, b.id),
                tuple(sorted(roles.items())),
                ((var, "6D"),) if var else (),
            )
            (instance,) = expand_group([match], ws.index)
            added = ws.apply(instance)
            if not added:  # no better than a chain joined already (Workspace._admit)
                return None
            record = made[(a.id, b.id)] = ws.index.edges[added[0]]
        items[i : i + 2] = [record]
    return items[0]


def plan(
    srg: nx.MultiDiGraph,
    templates: Sequence[Template],
    query: Query,
    *,
    slack: int = DEFAULT_SLACK,
    per_relation: int = DEFAULT_PER_RELATION,
    cache: PartCache | None = None,
) -> list[Solution]:
    """All distinct solutions of ``query`` on ``srg``, best first; raises :class:`NoSolutionError`.

    The first solution is the best derivation by the cost model; the whole list is what the
    design tool shows with ``--all``. With a ``cache``, the derivations of parts between cut
    frames are shared with other plans using the same cache (:class:`PartCache`).

    Python's cyclic garbage collector is paused while it runs
    (:func:`ubitrack_agent.core.heap.collector_paused`, process-wide): a plan keeps what it
    builds until it returns, where the collector would traverse it again and again (a fifth to
    a third of a plan's CPU in a room of 200-1,000 trackers), and it leaves no reference
    cycle, so reference counting frees all of it when it returns.
    """
    with collector_paused():
        return _plan(srg, templates, query, slack, per_relation, cache)


def _plan(
    srg: nx.MultiDiGraph,
    templates: Sequence[Template],
    query: Query,
    slack: int,
    per_relation: int,
    cache: PartCache | None,
) -> list[Solution]:
    """:func:`plan`, the collector paused."""
    absent = [n for n in (query.source, query.target) if n not in srg]
    if absent and not query.static and any(t.introduced for t in templates):
        raise NoSolutionError(
            f"frame(s) {', '.join(absent)} not in the SRG (a calibration introduces a frame "
            f"only for a static query, which names the frame it is rigidly attached to)"
        )
    new = introducible_frames(srg, templates, query)
    frames = relevant_frames(srg, query.source, query.target, slack, new)
    goal = (query.source, query.target)
    if not query.static:  # its chains lie on short ways without a cycle (Workspace._on_a_way)
        around = either_way(srg)
        longest = _span(srg, frames, goal, query.type, around) + slack
        frames = short_way_frames(around, frames, *goal, longest)
    chain = next((t for t in templates if t.signature == "chain" and "6D" in _chain_types(t)), None)
    chained = chain is not None and not query.static and query.type == "6D"
    parts = cut_frames(srg, frames, *goal) if chained else []
    if len(parts) > 1:
        found = _plan_parts(srg, templates, query, parts, slack, per_relation, cache, chain)
    else:
        rigid = [(query.source, query.target)] if query.static else []
        ws = saturate(srg, templates, frames, query.type, rigid, per_relation, goal, new, slack)
        found = solutions(ws, query)
    if not found:
        kind = "static " if query.static else ""
        why = (
            f"frame {new[0]} is not in the SRG and no calibration introduces it"
            if new
            else "the frames are connected, but no combination of patterns yields that edge"
        )
        raise NoSolutionError(
            f"no derivation of {kind}{query.type} {query.source}->{query.target}: {why} "
            f"(frames considered: {', '.join(sorted(frames))})"
        )
    return found
