"""Pattern detection (paper section 5.1): find pattern instances in an SRG and expand them.

Detection has the three steps of section 5.1:

1. :func:`find_matches` finds all occurrences ``G[alpha'(P)]`` of the *unexpanded* pattern: a
   seeded backtracking search that binds the template's input edges one by one to typed,
   attributed SRG edges (the candidates are the edges adjacent to an already bound frame, or the
   edges of the (type, static) partition), so the search never enumerates unrelated subgraphs.
2. :func:`expand_group` unifies compatible occurrences into inclusion-maximal collections
   (sets of pairwise compatible occurrences, each grown greedily from one occurrence:
   :func:`copy_sets`, polynomial where every maximal clique would be exponential).
3. A collection is kept as a *space* expansion if each correspondence edge is represented
   ``m`` times with ``m`` in ``M_P``, as a *time* expansion if it is represented once, its
   correspondence edges are dynamic and every other edge is static, and rejected otherwise.

Bookkeeping against redundant derivations lives here too: every edge carries the set of
measured edges it depends on (``sources``); the inputs of one occurrence must not share a
source (:func:`independent`), the copies of a space expansion must each add information, and
an input may exclude the outputs of given patterns (``not_from``: no inverse of an inverse).

A role no input binds (:attr:`Template.introduced`, the tip of a tip calibration) is bound,
once the inputs are, to a frame the query names and the SRG lacks (:attr:`EdgeIndex.new_frames`);
the outputs to such a frame hold only where the query declares it rigid (:func:`_time_ok`).
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable, Container, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from itertools import permutations
from typing import NamedTuple

from ubitrack_agent.graph.srg import Quality
from ubitrack_agent.graph.templates import Correspondence, InputSpec, Template


@dataclass(frozen=True)
class EdgeRecord:
    """One edge of the working SRG as the matcher sees it (measured or inferred).

    ``time_integrated`` marks a static edge produced by a time expansion (a calibration result);
    ``canon`` identifies the computation up to concatenation order and inversion (used to drop
    derivations that differ only in how a chain was bracketed or which way it was inverted).
    ``hops`` is the length of the way through the SRG the edge takes: 1 for a measured edge, the
    sum of its links' for a chain, the distance between its frames for any other step;
    ``frames`` are the frames its sources join. ``signature`` describes the derivation
    whole (its template, expansion, output and its inputs' signatures, recursively, copies in
    their own order; a measured edge by its key): unlike ``canon`` it tells bracketings apart,
    and unlike ``id`` it does not depend on the order in which steps were made, so ties of
    equal cost are broken on it (``planner._ranked``). Nested tuples: shared with the inputs'
    records, built in ``O(inputs)``, and compared in the order of their names, so renaming the
    measured edges' keys in order keeps every comparison (``planner._renamed``).
    """

    id: str
    source: str
    target: str
    type: str
    static: bool
    mode: str
    measured: bool
    provider: str
    quality: Quality
    sources: frozenset[str]
    cost: float
    canon: str
    leaves: tuple[str, ...] = ()
    pattern: str | None = None
    step: str | None = None
    time_integrated: bool = False
    steps: frozenset[str] = frozenset()
    providers: frozenset[str] = frozenset()
    hops: int = 1
    frames: frozenset[str] = frozenset()
    signature: tuple = ()


@dataclass
class EdgeIndex:
    """Adjacency by (frame, type) and (type, static) partitions of the working SRG, updated
    as edges are inferred (the partitioning of section 5.1 that keeps the subgraph search
    small).
    ``new_frames`` are frames a query names that have no edge yet: only a pattern's introduced
    roles bind them."""

    edges: dict[str, EdgeRecord] = field(default_factory=dict)
    out: dict[tuple[str, str], list[str]] = field(default_factory=lambda: defaultdict(list))
    inn: dict[tuple[str, str], list[str]] = field(default_factory=lambda: defaultdict(list))
    partitions: dict[tuple[str, bool], list[str]] = field(default_factory=lambda: defaultdict(list))
    rigid: dict[str, set[str]] = field(default_factory=lambda: defaultdict(set))
    measured_rigid: set[frozenset[str]] = field(default_factory=set)
    dynamic_measured: set[str] = field(default_factory=set)
    retired: set[str] = field(default_factory=set)
    new_frames: tuple[str, ...] = ()
    space_only: bool = False
    """Set by the planner when no time expansion can add an edge (every rigid relation is
    measured: a dynamic query), so an occurrence with correspondence serves only as a copy of
    a space expansion: :func:`find_matches` then holds back seeds that cannot be copies yet
    (:attr:`waiting`) and :func:`expand_group` forms no time expansion."""
    waiting: dict[str, dict[tuple[str, str, str], list[tuple[int, str]]]] = field(
        default_factory=dict
    )
    """Seeds held back, by template name and then by the edges they wait for (``out`` or
    ``inn``, frame, type): each one's input position and edge id (:func:`find_matches`)."""
    copy_ends: dict[str, tuple[int, list[tuple[str, str] | None]]] = field(default_factory=dict)
    """:func:`_copy_ends` by template name (it depends on :attr:`space_only`, set first)."""
    copies_fit: dict[tuple, bool] = field(default_factory=dict)
    """:func:`compatible` of two occurrences, memoised: a group's occurrences are gathered into
    sets again each time the group gains one, and their records never change."""
    copies: dict[tuple[str, tuple[str, ...]], _Copy] = field(default_factory=dict)
    """What :func:`copy_sets` reads of an occurrence (by template name and input edges), for
    the same reason."""

    def add(self, record: EdgeRecord) -> None:
        """Insert ``record`` into every index."""
        self.edges[record.id] = record
        self.out[(record.source, record.type)].append(record.id)
        self.inn[(record.target, record.type)].append(record.id)
        self.partitions[(record.type, record.static)].append(record.id)
        if record.measured and not record.static:
            self.dynamic_measured.add(record.id)
        if record.measured and record.static:
            self.add_rigid(record.source, record.target)
            self.measured_rigid.add(frozenset((record.source, record.target)))

    def retire(self, edge_id: str) -> None:
        """Stop offering ``edge_id`` to the matcher (its record stays, for provenance)."""
        record = self.edges[edge_id]
        self.retired.add(edge_id)
        self.out[(record.source, record.type)].remove(edge_id)
        self.inn[(record.target, record.type)].remove(edge_id)
        self.partitions[(record.type, record.static)].remove(edge_id)

    def count(self, direction: str, frame: str, edge_type: str) -> int:
        """How many edges of ``edge_type`` leave (``direction`` ``"out"``) or enter
        (``"inn"``) ``frame``, retired ones not counted."""
        return len((self.out if direction == "out" else self.inn).get((frame, edge_type), ()))

    def add_rigid(self, a: str, b: str) -> None:
        """Declare frames ``a`` and ``b`` rigidly connected (a static relationship)."""
        self.rigid[a].add(b)
        self.rigid[b].add(a)

    def is_rigid(self, a: str, b: str) -> bool:
        """True if ``a`` and ``b`` are known to be rigidly connected."""
        return b in self.rigid.get(a, ())

    def is_measured_rigid(self, a: str, b: str) -> bool:
        """True if a measured static edge joins ``a`` and ``b`` (their relation is known)."""
        return frozenset((a, b)) in self.measured_rigid


@dataclass(frozen=True)
class Match:
    """An occurrence of an unexpanded pattern: input edge ids in template order, role bindings
    and type variable bindings (all as sorted tuples so that matches hash)."""

    template: Template
    edges: tuple[str, ...]
    roles: tuple[tuple[str, str], ...]
    types: tuple[tuple[str, str], ...]

    @cached_property
    def role_map(self) -> dict[str, str]:
        """The role bindings as a mapping (made once: grouping, compatibility and expansion
        read them again and again)."""
        return dict(self.roles)


@dataclass(frozen=True)
class Instance:
    """An instance ``G[alpha(P-bar)]`` of an expanded pattern, ready to be applied.

    ``inputs`` maps each input name to its edge ids (several for the correspondence edges of a
    space expansion, one copy per duplicated node), ``outputs`` lists the output edges as
    ``(name, source, target, type, static, mode)``.
    """

    template: Template
    expansion: str
    inputs: tuple[tuple[str, tuple[str, ...]], ...]
    outputs: tuple[tuple[str, str, str, str, bool, str], ...]

    @property
    def key(self) -> tuple[str, str, tuple[tuple[str, tuple[str, ...]], ...]]:
        """Identity of the instance: template, expansion and input bindings."""
        return (self.template.name, self.expansion, self.inputs)

    def input_edges(self) -> Iterator[str]:
        """Every bound input edge id."""
        for _, ids in self.inputs:
            yield from ids


def independent(a: EdgeRecord, b: EdgeRecord, index: EdgeIndex, *, strict: bool) -> bool:
    """True if edges ``a`` and ``b`` may be inputs of one pattern occurrence (section 5.1).

    They must not depend on a common measured edge. Unless ``strict``, a static edge obtained by
    integration over time may share *dynamic* sources with the other edge: the paper's exception
    for averaged static edges, which hold information the instantaneous samples do not.
    """
    if a.sources.isdisjoint(b.sources):
        return True
    shared = a.sources & b.sources
    if strict or not (a.time_integrated or b.time_integrated):
        return False
    return shared <= index.dynamic_measured


# --- step 1: occurrences of the unexpanded pattern ----------------------------------------------


def _bind(
    spec: InputSpec,
    edge: EdgeRecord,
    template: Template,
    roles: dict[str, str],
    types: dict[str, str],
) -> list[tuple[dict[str, str], str]] | None:
    """Check the predicates of ``spec`` on ``edge`` and bind its roles and type variable in
    place; return the bindings made (for :func:`_unbind`), or ``None`` if ``edge`` does not fit
    (then nothing is bound)."""
    if spec.has_predicates and (
        (spec.static is not None and edge.static != spec.static)
        or (spec.mode is not None and edge.mode != spec.mode)
        or (spec.measured is not None and edge.measured != spec.measured)
        or edge.pattern in spec.not_from
    ):
        return None
    made: list[tuple[dict[str, str], str]] = []
    var = spec.type_var
    if var is not None:
        bound = types.get(var)
        if bound is None:
            if edge.type not in template.type_vars[var]:
                return None
            types[var] = edge.type
            made.append((types, var))
        elif bound != edge.type:
            return None
    elif spec.type != edge.type:
        return None
    for role, node in ((spec.source, edge.source), (spec.target, edge.target)):
        bound = roles.get(role)
        if bound is None and node not in roles.values():
            roles[role] = node
            made.append((roles, role))
        elif bound != node:
            _unbind(made)
            return None
    return made


def _unbind(made: list[tuple[dict[str, str], str]]) -> None:
    for mapping, key in made:
        del mapping[key]


def _rigid_links(template: Template) -> list[tuple[str, str]]:
    """Role pairs a time-only template requires to be rigid: its static outputs between frames
    of the SRG (an introduced frame's relations are the query's to declare, :func:`_time_ok`)."""
    if not template.time_only:
        return []
    new = set(template.introduced)
    return [
        (o.source, o.target)
        for o in template.outputs
        if o.static is True and not {o.source, o.target} & new
    ]


def _introductions(
    template: Template, index: EdgeIndex, roles: Mapping[str, str]
) -> Iterator[dict[str, str]]:
    """Bindings of the template's introduced roles to distinct new frames not bound already;
    a single empty binding for a template that introduces none."""
    if not template.introduced:
        yield {}
        return
    free = [frame for frame in index.new_frames if frame not in roles.values()]
    for frames in permutations(free, len(template.introduced)):
        yield dict(zip(template.introduced, frames, strict=True))


def _candidates(
    spec: InputSpec,
    roles: Mapping[str, str],
    types: Mapping[str, str],
    template: Template,
    index: EdgeIndex,
    kinds: Sequence[str] | None = None,
) -> Sequence[str]:
    """Edge ids that could bind ``spec`` given the roles and types bound so far (most selective
    first: the edges of a bound frame of a possible type; of ``kinds`` only, if given)."""
    var = spec.type_var
    if kinds is None and var is not None:
        kinds = (types[var],) if var in types else template.type_vars[var]
    elif kinds is None:
        kinds = (spec.type,)
    if spec.source in roles:
        frame, adjacency = roles[spec.source], index.out
    elif spec.target in roles:
        frame, adjacency = roles[spec.target], index.inn
    else:
        for a, b in _rigid_links(template):
            for near, far in ((a, b), (b, a)):
                if far in roles and near in (spec.source, spec.target):
                    partners = sorted(index.rigid.get(roles[far], ()))
                    adjacency = index.out if near == spec.source else index.inn
                    return [
                        e for node in partners for t in kinds for e in adjacency.get((node, t), ())
                    ]
        statics = (False, True) if spec.static is None else (spec.static,)
        return [e for t in kinds for s in statics for e in index.partitions.get((t, s), ())]
    if len(kinds) == 1:
        return adjacency.get((frame, kinds[0]), ())
    return [e for t in kinds for e in adjacency.get((frame, t), ())]


def _next_input(template: Template, bound: Mapping[int, str], roles: Mapping[str, str]) -> int:
    """Index of the unbound input to bind next: one touching a bound role if possible."""
    best, best_score = -1, -1
    for i, spec in enumerate(template.inputs):
        if i in bound:
            continue
        score = (spec.source in roles) + (spec.target in roles)
        if score > best_score:
            best, best_score = i, score
    return best


Viable = Callable[[Mapping[str, str], Mapping[str, str], Mapping[int, str]], bool]
"""A caller's test of a partial occurrence (role bindings, type bindings, bound input edge ids
by input index): ``False`` if no occurrence completing it is wanted, so the search drops it
before binding the remaining inputs (and a complete one before it is built)."""


def _any_binding(
    roles: Mapping[str, str], types: Mapping[str, str], bound: Mapping[int, str]
) -> bool:
    return True


class LastTest(NamedTuple):
    """A caller's test of the edges that would bind the last unbound input (:data:`LastLink`)."""

    fits: Callable[[EdgeRecord], bool]
    """Whether the occurrence the edge completes is wanted; asked before the edge is bound."""
    narrow: Callable[[Sequence[str]], Sequence[str]] | None = None
    """The candidate edge ids (in order) without some that :attr:`fits` rejects, known by a
    cheaper test than asking it of each (``None``: all are asked)."""


NARROWED_FROM = 16
"""A last input's candidates are narrowed (:attr:`LastTest.narrow`) only where there are more
than this many: for a few, asking ``fits`` of each costs less than narrowing them first."""

LastLink = Callable[
    [InputSpec, Mapping[str, str], Mapping[str, str], Mapping[int, str]],
    LastTest | None,
]
"""A caller's test of the occurrences an edge would complete by binding the last unbound
input: given its specification, the role and type bindings and the bound input edge ids so
far, a :class:`LastTest` (``None``: no test, :data:`Viable` is asked after binding). It must
pass exactly the edges whose completed occurrence :data:`Viable` would pass: the search binds
only those and does not ask :data:`Viable` again. What the edges share is worked out once, not
for each candidate."""


def _extend(
    template: Template,
    index: EdgeIndex,
    bound: dict[int, str],
    roles: dict[str, str],
    types: dict[str, str],
    viable: Viable = _any_binding,
    seeds: frozenset[str] = frozenset(),
    seeded_at: int = 0,
    last: LastLink | None = None,
) -> Iterator[Match]:
    """Occurrences completing the partial one (``bound``, ``roles``, ``types``); an input before
    ``seeded_at`` binds no edge of ``seeds`` (:func:`find_matches`); ``last`` tests the edge of
    the last input before it is bound."""
    if len(bound) == len(template.inputs):
        yield from _completed(template, index, bound, roles, types)
        return
    i = _next_input(template, bound, roles)
    spec = template.inputs[i]
    edges = index.edges
    chosen = [edges[b] for b in bound.values()]
    if len(chosen) == 1:  # the seed alone (most templates have two inputs)
        taken, integrated = chosen[0].sources, chosen[0].time_integrated
    else:
        taken = frozenset().union(*(other.sources for other in chosen))
        integrated = any(other.time_integrated for other in chosen)
    not_seeds = i < seeded_at
    completes = len(bound) + 1 == len(template.inputs)
    test = last(spec, roles, types, bound) if completes and last is not None else None
    check = None if test is None else test.fits
    introduces = bool(template.introduced)
    positions = range(len(template.inputs))
    free = viable is _any_binding  # no test to ask
    var = spec.type_var
    kinds = None
    if not free and var is not None and var not in types:
        kinds = _viable_kinds(template, var, roles, types, bound, viable)
    candidates = _candidates(spec, roles, types, template, index, kinds)
    if test is not None and test.narrow is not None and len(candidates) > NARROWED_FROM:
        candidates = test.narrow(candidates)
    for edge_id in candidates:
        if not_seeds and edge_id in seeds:
            continue
        edge = edges[edge_id]
        # bookkeeping of section 5.1: inputs of one occurrence must not share a measured edge
        # (which also keeps an edge from binding twice); the hottest loop of the search, so
        # the sources of the inputs bound so far are tested at once, and one by one only
        # where independent()'s exception for time-integrated edges may apply
        sources = edge.sources
        if not sources.isdisjoint(taken):
            if not (integrated or edge.time_integrated):
                continue
            if any(
                not sources.isdisjoint(other.sources)
                and (edge is other or not independent(edge, other, index, strict=False))
                for other in chosen
            ):
                continue
        if check is not None and not check(edge):
            continue
        made = _bind(spec, edge, template, roles, types)
        if made is None:
            continue
        bound[i] = edge_id
        if free or check is not None or viable(roles, types, bound):
            if not completes:
                yield from _extend(
                    template, index, bound, roles, types, viable, seeds, seeded_at, last
                )
            elif introduces:
                yield from _completed(template, index, bound, roles, types)
            else:  # the last input: the occurrence is complete (no generator for it)
                yield Match(
                    template,
                    tuple(map(bound.__getitem__, positions)),
                    tuple(sorted(roles.items())),
                    tuple(sorted(types.items())),
                )
        del bound[i]
        _unbind(made)


def _viable_kinds(
    template: Template,
    var: str,
    roles: Mapping[str, str],
    types: dict[str, str],
    bound: Mapping[int, str],
    viable: Viable,
) -> list[str]:
    """The types the unbound type variable ``var`` may take in an occurrence completing the
    partial one: those for which ``viable`` does not reject it with ``var`` bound, asked once
    per type before the candidates of that type are listed (a point is carried only into a
    query frame: a chain from any other frame takes no 3D link)."""
    kinds = []
    for kind in template.type_vars[var]:
        types[var] = kind
        if viable(roles, types, bound):
            kinds.append(kind)
    del types[var]
    return kinds


def _completed(
    template: Template,
    index: EdgeIndex,
    bound: Mapping[int, str],
    roles: Mapping[str, str],
    types: Mapping[str, str],
) -> Iterator[Match]:
    """The occurrences of a complete binding: one per binding of the introduced roles."""
    for introduced in _introductions(template, index, roles):
        yield Match(
            template,
            tuple(bound[i] for i in range(len(template.inputs))),
            tuple(sorted({**roles, **introduced}.items())),
            tuple(sorted(types.items())),
        )


def _admissible(match: Match, index: EdgeIndex) -> bool:
    """Rigid links of a time-only pattern (independence is checked while binding)."""
    if not match.template.time_only:
        return True
    roles = match.role_map
    return all(index.is_rigid(roles[a], roles[b]) for a, b in _rigid_links(match.template))


def _always(match: Match, index: EdgeIndex) -> bool:
    return True


def _inputs_of_type(template: Template, edge_type: str) -> list[tuple[int, InputSpec]]:
    """The inputs (index, specification) an edge of ``edge_type`` may bind."""
    return [
        (i, spec)
        for i, spec in enumerate(template.inputs)
        if spec.type == edge_type
        or (spec.type.startswith("$") and edge_type in template.type_vars[spec.type[1:]])
    ]


def find_matches(
    template: Template,
    index: EdgeIndex,
    seeds: Iterable[str] | None = None,
    viable: Viable = _any_binding,
    last: LastLink | None = None,
) -> Iterator[Match]:
    """Occurrences of the unexpanded ``template`` in ``index`` that pass the bookkeeping rules.

    With ``seeds`` (edge ids, e.g. the edges inferred in the last round), only occurrences using
    at least one seed are found, each once (semi-naive evaluation with the delta rule of
    Bancilhon and Ramakrishnan, "An amateur's introduction to recursive query processing
    strategies", SIGMOD 1986: an occurrence is found from its first input bound to a seed,
    the inputs before that one bind no seed). ``viable`` prunes partial occurrences (the
    planner's test of which chains serve a query), checked after each bound input; ``last``
    (:data:`LastLink`) before the last input is bound.
    """
    if seeds is None:
        start = _extend(template, index, {}, {}, {}, viable, last=last)
        yield from (m for m in start if _admissible(m, index))
        return
    seeds = list(dict.fromkeys(seeds))
    least, ends = _copy_ends(template, index)
    waiting = index.waiting.setdefault(template.name, {}) if least else {}
    ready = _ready(waiting, index, least)
    fresh = frozenset(seeds).union(seed for _, seed in ready)
    # what every occurrence is checked for, decided once for the template: rigid links apply
    # to time-only patterns, introduced roles take a binding of their own
    admissible = _admissible if template.time_only else _always
    single = len(template.inputs) == 1 and not template.introduced and not template.time_only
    free = viable is _any_binding  # no test to ask
    inputs_of_type: dict[str, list[tuple[int, InputSpec]]] = {}

    positions = []
    for seed in seeds:
        edge_type = index.edges[seed].type
        fitting = inputs_of_type.get(edge_type)
        if fitting is None:
            fitting = inputs_of_type[edge_type] = _inputs_of_type(template, edge_type)
        for i, spec in fitting:
            positions.append((seed, i, spec))
    for i, seed in ready:  # held back, after the others: they touch no group first
        positions.append((seed, i, template.inputs[i]))
    for seed, i, spec in positions:
        edge = index.edges[seed]
        roles: dict[str, str] = {}
        types: dict[str, str] = {}
        bound = {i: seed}
        if _bind(spec, edge, template, roles, types) is None or not (
            free or viable(roles, types, bound)
        ):
            continue
        end = ends[i]
        if end is not None:
            direction, role = end
            if index.count(direction, roles[role], edge.type) < least:
                waiting.setdefault((direction, roles[role], edge.type), []).append((i, seed))
                continue
        if single:  # one input: the occurrence is complete (no generator for it)
            yield Match(
                template, (seed,), tuple(sorted(roles.items())), tuple(sorted(types.items()))
            )
            continue
        for match in _extend(template, index, bound, roles, types, viable, fresh, i, last):
            if admissible(match, index):
                yield match


def _copy_ends(template: Template, index: EdgeIndex) -> tuple[int, list[tuple[str, str] | None]]:
    """What :func:`find_matches` holds a seed back on: the least number of copies of a space
    expansion, and for each input of the correspondence that joins a duplicated role to one
    that is not, which edges of that role's frame bound the copies (``("out", role)`` for the
    edges out of it, ``("inn", role)`` into it; None for other inputs). ``(0, ...)`` when
    nothing is held back: time expansions may add edges, or one copy is enough.

    Why it is exact: when time expansions add nothing (:attr:`EdgeIndex.space_only`), an
    occurrence serves only as one of ``lo`` or more copies whose duplicated roles are
    pairwise different frames (:func:`compatible`), all sharing the other role's frame X
    (:func:`group_key`); so there are at most as many copies as X has edges of the seed's
    type, and a seed at an X with fewer than ``lo`` joins no expansion yet. It waits until X
    has ``lo`` (:func:`_ready`, in the first round it does) and is matched then, after the
    round's other seeds: a group that can be expanded in that round gains an occurrence from
    an edge new in it (X had fewer than ``lo`` edges in the round before), so it is touched
    in the same round and order as without waiting, with the same occurrences. In a room
    with 200 redundant trackers, the 3D-3D pose estimations between two trackers (each sees
    two bodies, the pattern needs three points) were 43,818 of 49,709 occurrences found and
    none expanded."""
    known = index.copy_ends.get(template.name)
    if known is None:
        known = index.copy_ends[template.name] = _copy_ends_of(template, index.space_only)
    return known


def _copy_ends_of(template: Template, space_only: bool) -> tuple[int, list[tuple[str, str] | None]]:
    """:func:`_copy_ends`, worked out."""
    corr = template.correspondence
    if not space_only or corr is None or "space" not in corr.expansions or corr.multiplicity.lo < 2:
        return 0, [None] * len(template.inputs)
    ends: list[tuple[str, str] | None] = []
    for spec in template.inputs:
        source_copied = spec.source in corr.expand_roles
        target_copied = spec.target in corr.expand_roles
        if spec.name not in corr.edges or source_copied == target_copied:
            ends.append(None)
        else:
            ends.append(("inn", spec.target) if source_copied else ("out", spec.source))
    return corr.multiplicity.lo, ends


def _ready(
    waiting: dict[tuple[str, str, str], list[tuple[int, str]]], index: EdgeIndex, least: int
) -> list[tuple[int, str]]:
    """The held-back seeds (:func:`_copy_ends`) whose frame has ``least`` edges now, taken
    out of ``waiting``; retired edges are dropped (no expansion takes them).
    ``O(frames waited on)`` per call."""
    ready: list[tuple[int, str]] = []
    for key in [k for k in waiting if index.count(*k) >= least]:
        ready.extend(p for p in waiting.pop(key) if p[1] not in index.retired)
    return ready


# --- steps 2 and 3: unification into expansions --------------------------------------------------


def group_key(match: Match) -> tuple:
    """Occurrences that may be unified share everything but the correspondence copies: the
    non-duplicated roles, the edges outside the correspondence and the type bindings."""
    corr = match.template.correspondence
    if corr is None:
        return (match.edges,)
    copied = match.template.in_correspondence
    fixed_edges = tuple(e for c, e in zip(copied, match.edges, strict=True) if not c)
    expanded = corr.expand_roles
    fixed_roles = tuple(pair for pair in match.roles if pair[0] not in expanded)
    return (fixed_roles, fixed_edges, match.types)


def _corr_edges(match: Match) -> list[str]:
    copied = match.template.in_correspondence
    return [e for c, e in zip(copied, match.edges, strict=True) if c]


def compatible(a: Match, b: Match, index: EdgeIndex) -> bool:
    """Two occurrences can be copies in one space expansion (section 5.1); memoised in
    :attr:`EdgeIndex.copies_fit`."""
    key = (a.template.name, a.edges, a.roles, b.edges, b.roles)
    known = index.copies_fit.get(key)
    if known is None:
        known = index.copies_fit[key] = _compatible(a, b, index)
    return known


def _compatible(a: Match, b: Match, index: EdgeIndex) -> bool:
    corr = a.template.correspondence
    assert corr is not None
    roles_a, roles_b = a.role_map, b.role_map
    if any(roles_a[r] == roles_b[r] for r in corr.expand_roles):
        return False
    ea, eb = _corr_edges(a), _corr_edges(b)
    if set(ea) & set(eb):
        return False
    if corr.independent:
        return all(
            independent(index.edges[x], index.edges[y], index, strict=True) for x in ea for y in eb
        )
    sources_a = frozenset().union(*(index.edges[x].sources for x in ea))
    sources_b = frozenset().union(*(index.edges[y].sources for y in eb))
    return not (sources_a <= sources_b or sources_b <= sources_a)


def _outputs(
    template: Template,
    roles: Mapping[str, str],
    types: Mapping[str, str],
    inputs: list[EdgeRecord],
    expansion: str,
) -> tuple[tuple[str, str, str, str, bool, str], ...]:
    all_static = all(e.static for e in inputs)
    any_push = any(e.mode == "push" for e in inputs)
    out = []
    for spec in template.outputs:
        edge_type = types[spec.type[1:]] if spec.type.startswith("$") else spec.type
        static = (expansion == "time" or all_static) if spec.static == "inherit" else spec.static
        mode = ("push" if any_push else "pull") if spec.mode == "inherit" else spec.mode
        out.append((spec.name, roles[spec.source], roles[spec.target], edge_type, static, mode))
    return tuple(out)


def _time_ok(match: Match, index: EdgeIndex) -> bool:
    """Conditions of a time expansion: correspondence edges dynamic, all other inputs static,
    and every output joins frames known to be rigid (time expansions yield static edges).

    An output to an introduced frame is exempt: the SRG knows nothing of that frame, so the
    query says which of its relations is rigid (the tip in the marker, or the pivot in the
    tracker); at least one must be, and the planner adds only those."""
    template = match.template
    corr = template.correspondence
    assert corr is not None
    for spec, edge_id in zip(template.inputs, match.edges, strict=True):
        if index.edges[edge_id].static != (spec.name not in corr.edges):
            return False
    roles = match.role_map
    new = template.introduced
    introducing = rigid_introduced = False
    for o in template.outputs:
        rigid = index.is_rigid(roles[o.source], roles[o.target])
        if o.source in new or o.target in new:
            introducing = True
            rigid_introduced = rigid_introduced or rigid
        elif not rigid:
            return False
    return rigid_introduced or not introducing


def _copy_order(match: Match, index: EdgeIndex) -> tuple:
    """How good a copy is for a space expansion: its correspondence edges' summed cost, then
    their canonical computations and signatures (:attr:`EdgeRecord.signature`: a total order
    independent of announcement and of the order in which steps were made)."""
    edges = [index.edges[e] for e in _corr_edges(match)]
    return (sum(e.cost for e in edges), [e.canon for e in edges], [e.signature for e in edges])


@dataclass(frozen=True)
class _Copy:
    """What :func:`copy_sets` reads of one occurrence, gathered once (so the ``n**2`` pairs
    compare precomputed values): its rank (:func:`_copy_order`), the frames of its expanded
    roles (as ``(role index, frame)`` pairs: two copies that share one share a frame in a
    role), its correspondence edges and the union of their sources (:func:`compatible`), and
    the canonical computations and signatures of its inputs (the order of a set's copies)."""

    order: tuple
    expanded: frozenset[tuple[int, str]]
    edges: frozenset[str]
    sources: frozenset[str]
    computations: tuple[list[str], list[tuple]]


def _copy_of(match: Match, index: EdgeIndex) -> _Copy:
    """The :class:`_Copy` of ``match``, memoised in :attr:`EdgeIndex.copies` (an occurrence's
    roles other than introduced ones, which no correspondence expands, follow from its edges)."""
    key = (match.template.name, match.edges)
    known = index.copies.get(key)
    if known is None:
        corr = match.template.correspondence
        assert corr is not None
        roles = match.role_map
        edges = _corr_edges(match)
        known = index.copies[key] = _Copy(
            _copy_order(match, index),
            frozenset(enumerate(roles[r] for r in corr.expand_roles)),
            frozenset(edges),
            frozenset().union(*(index.edges[e].sources for e in edges)),
            (
                [index.edges[e].canon for e in match.edges],
                [index.edges[e].signature for e in match.edges],
            ),
        )
    return known


def _fitting(i: int, copies: list[_Copy], independent_copies: bool) -> int:
    """The copies after the ``i``-th that may be copies together with it (:func:`_compatible`
    on precomputed values), as bits: no expanded role bound to one frame in both, no
    correspondence edge in common, and sources that add information (strict independence of
    every pair of their edges, :func:`independent`, is disjointness of the unions of their
    sources). One call per row of the ``n**2`` pairs, its tests on frozensets."""
    a = copies[i]
    placed, edges, sources = a.expanded, a.edges, a.sources
    row = 0
    for j in range(i + 1, len(copies)):
        b = copies[j]
        if not (placed.isdisjoint(b.expanded) and edges.isdisjoint(b.edges)):
            continue
        if independent_copies:
            if sources.isdisjoint(b.sources):
                row |= 1 << j
        elif not (sources <= b.sources or b.sources <= sources):
            row |= 1 << j
    return row


def _maximal_cliques(fits: list[int]) -> list[int]:
    """Every maximal clique (as a bit set) of the graph whose vertex ``i`` has the neighbours
    ``fits[i]`` (no self loops): Bron and Kerbosch 1973 with Tomita's pivot (the vertex of
    ``P | X`` with most neighbours in ``P``), on bit sets. ``O(3**(n/3))``."""
    found: list[int] = []
    _expand_cliques(fits, found, 0, (1 << len(fits)) - 1, 0)
    return found


def _expand_cliques(fits: list[int], found: list[int], clique: int, p: int, x: int) -> None:
    """One call of Bron-Kerbosch with pivot (:func:`_maximal_cliques`): the maximal cliques
    extending ``clique`` by vertices of ``p`` and none of ``x``, appended to ``found``. A
    module function, not a closure: a recursive closure refers to itself and would leave its
    frame's objects to the cyclic collector."""
    if not p:
        if not x:
            found.append(clique)
        return
    rest, pivot_fits, most = p | x, 0, -1
    while rest:
        low = rest & -rest
        neighbours = fits[low.bit_length() - 1]
        count = (p & neighbours).bit_count()
        if count > most:
            pivot_fits, most = neighbours, count
        rest ^= low
    candidates = p & ~pivot_fits
    while candidates:
        low = candidates & -candidates
        neighbours = fits[low.bit_length() - 1]
        _expand_cliques(fits, found, clique | low, p & neighbours, x & neighbours)
        p &= ~low
        x |= low
        candidates ^= low


EXACT_COPIES = 8
"""Most occurrences in a group for which :func:`copy_sets` also takes every maximal set."""


def copy_sets(members: list[Match], index: EdgeIndex) -> list[list[Match]]:
    """Sets of pairwise compatible occurrences to expand in space, each inclusion-maximal.

    Enumerating every maximal clique of the compatibility graph (Bron-Kerbosch) is exponential:
    with ``a`` derivations of each of ``m`` features it finds ``a**m`` sets, and the planner
    applied 630,435 pattern instances for one cross-room query. Instead each occurrence seeds
    one set, completed greedily with the best compatible occurrences (:func:`_copy_order`):
    the cheapest copies of every frame together, and for each alternative copy a set built
    around it (a tracker's path seeds the set of that tracker's derivations). With ``n``
    occurrences this is ``O(n**3)`` bit operations on a precomputed compatibility matrix
    (:func:`compatible` of each pair, on values gathered once per occurrence) and at
    most ``n`` sets. Each set is maximal: an occurrence left out conflicts with one taken.
    Greedy sets can miss the best one (a cheap copy taken first may conflict with two that
    together are worth more), so a group of at most :data:`EXACT_COPIES` occurrences also gets
    every maximal set (Bron-Kerbosch, :func:`_maximal_cliques`; at most ``3**(n/3)``, 18
    for eight): exact where the sets are few, polynomial where they would explode.

    For a fusion, the cheapest ``k`` compatible copies are a set for every ``k`` too (at most
    ``n`` more): each fused estimate adds its sensors and steps to the cost, so fusing the best
    few may cost less than fusing all (in a room with eight trackers, three of them).
    """
    ranked = sorted(((_copy_of(m, index), m) for m in members), key=lambda cm: cm[0].order)
    order = [m for _, m in ranked]
    copies = [c for c, _ in ranked]
    n = len(order)
    corr = members[0].template.correspondence if members else None
    independent_copies = corr is not None and corr.independent
    fits = [0] * n  # bit j of fits[i]: order[i] and order[j] may be copies together
    for i in range(n):
        row = _fitting(i, copies, independent_copies)
        fits[i] |= row
        while row:
            low = row & -row
            fits[low.bit_length() - 1] |= 1 << i
            row ^= low
    prefixes = bool(members) and members[0].template.cost.rule == "fusion"
    found: dict[int, None] = {}
    for seed in range(n):
        chosen, allowed = 1 << seed, fits[seed]
        for j in range(n):
            if allowed >> j & 1:
                chosen |= 1 << j
                allowed &= fits[j]
                if prefixes and seed == 0:
                    found.setdefault(chosen)
        found.setdefault(chosen)
    if n <= EXACT_COPIES:  # few: every maximal set, as many as 3**(n/3) (Moon and Moser 1965)
        cliques = [[j for j in range(n) if clique >> j & 1] for clique in _maximal_cliques(fits)]
        for clique in sorted(cliques):
            found.setdefault(sum(1 << j for j in clique))

    def by_computation(j: int) -> tuple[list[str], list[tuple]]:
        return copies[j].computations

    return [
        [order[j] for j in sorted((j for j in range(n) if chosen >> j & 1), key=by_computation)]
        for chosen in found
    ]


CopySets = Callable[[list[Match], EdgeIndex], list[list[Match]]]
"""How a group's compatible occurrences are gathered into sets of copies (:func:`copy_sets`)."""


def _may_expand(members: list[Match], index: EdgeIndex) -> bool:
    """Whether a group of occurrences can yield an expansion at all, before its sets are
    formed: a space expansion needs as many copies as the multiplicity's least, pairwise
    compatible and so each with its own frames in the expanded roles (:func:`compatible`); a
    time expansion needs an occurrence meeting :func:`_time_ok`. ``O(members)``."""
    corr = members[0].template.correspondence
    assert corr is not None
    least = corr.multiplicity.lo
    if "space" in corr.expansions and len(members) >= least:
        if not corr.expand_roles:
            return True
        distinct = {tuple(m.role_map[r] for r in corr.expand_roles) for m in members}
        if len(distinct) >= least:
            return True
    return time_expandable(members, index)


def time_expandable(members: Sequence[Match], index: EdgeIndex) -> bool:
    """Whether some occurrence of a group may be expanded in time (:func:`_time_ok`).
    ``O(members)``."""
    corr = members[0].template.correspondence
    assert corr is not None
    return _timed(corr, index) and any(_time_ok(m, index) for m in members)


def _timed(corr: Correspondence, index: EdgeIndex) -> bool:
    """Whether time expansions of the pattern are formed: allowed, and able to add an edge
    (not :attr:`EdgeIndex.space_only`)."""
    return "time" in corr.expansions and not index.space_only


def expand_group(
    members: list[Match],
    index: EdgeIndex,
    copies: CopySets = copy_sets,
    applied: Container[tuple] = frozenset(),
) -> list[Instance]:
    """Expanded instances from occurrences sharing one :func:`group_key` (steps 2 and 3).

    A template without correspondence yields one unexpanded instance per occurrence. Otherwise
    inclusion-maximal sets of pairwise compatible occurrences are formed (``copies``, by default
    :func:`copy_sets`; the test oracle passes every maximal clique) and each is kept (unless
    an instance of its key was ``applied`` already: a group is expanded again each time it
    gains an occurrence) as a space expansion (``m`` copies, ``m`` in the multiplicity), as a
    time expansion (a single occurrence meeting :func:`_time_ok`) or rejected.
    """
    template = members[0].template
    corr = template.correspondence
    if corr is None:
        return [
            Instance(
                template,
                "none",
                tuple((s.name, (e,)) for s, e in zip(template.inputs, m.edges, strict=True)),
                _outputs(
                    template,
                    m.role_map,
                    dict(m.types),
                    [index.edges[e] for e in m.edges],
                    "none",
                ),
            )
            for m in members
        ]
    if not _may_expand(members, index):
        return []
    instances = []
    for chosen in copies(members, index):
        expansions = []
        if "space" in corr.expansions and len(chosen) in corr.multiplicity:
            expansions.append("space")
        if len(chosen) == 1 and _timed(corr, index) and _time_ok(chosen[0], index):
            expansions.append("time")
        for expansion in expansions:
            inputs = tuple(
                (spec.name, tuple(m.edges[k] for m in chosen))
                if spec.name in corr.edges
                else (spec.name, (chosen[0].edges[k],))
                for k, spec in enumerate(template.inputs)
            )
            if (template.name, expansion, inputs) in applied:
                continue
            records = [index.edges[e] for _, ids in inputs for e in ids]
            outputs = _outputs(
                template, chosen[0].role_map, dict(chosen[0].types), records, expansion
            )
            instances.append(Instance(template, expansion, inputs, outputs))
    return instances
