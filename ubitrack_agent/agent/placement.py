"""Where each worker runs: near the data it reads (``docs/architecture.md``, "Placement").

The paper's service managers run the pattern processes on the hosts the agent chooses
(section 5.2.1); its example is a mobile setup whose camera and HMD have their own computer,
walking into a room with a tracker PC. Every data stream that crosses from one host to another
costs network latency and bandwidth, so the agent puts each component where its inputs are.
The rule, pure and deterministic (:func:`place`):

1. **Eligible hosts**: a live host manager that has every label required of the component
   (its template's ``host_labels``: ``camera``, ``gpu``, ...; for the producer of a queried
   relation also the labels its applications ask for) and runs fewer workers of this plan than
   its capacity. With none, the component is not placed and the reason is reported.
2. **Cost of a host**: each input whose data comes from another host costs one crossing (a
   static input :data:`STATIC_WEIGHT`: it is read once, not per frame); a queried relation the
   component publishes costs one crossing per other host an application asking for it runs on
   (so the last hop sits beside the application when that saves a crossing); plus
   :data:`LOAD_WEIGHT` times the host's load (the larger of the share of its capacity this plan
   uses and its CPU load per core, at most 1); and :data:`DOWNSTREAM_WEIGHT` if an application
   reads the relation its derivation ends in on other hosts only (so that between hosts
   equally near its inputs a fusion goes where the application is, and the last hop can
   follow it without a crossing: the greedy order of rule 3 cannot see that saving). Between
   hosts equally near the data and the applications, the less loaded one wins. An input of
   unknown origin costs nothing anywhere.
3. **Order**: components are placed producers first, so a consumer sees where its producers
   went; ties go to the host name first in order.
4. **No flapping**: a component already placed stays where it is while that host is eligible,
   unless another one is cheaper by at least :data:`MOVE_MARGIN` (a stream saved). A host
   that joins therefore takes over only the components it brings a stream closer to; a host
   that vanishes leaves its components to be placed again.
5. **Chains move together**: moving one component of a chain may save nothing while moving
   the chain does (a fusion and the last hop, both beside the A.R.T. while the HMD's host
   manager was away: either alone would still cross once). So the placement from scratch
   (rules 1 to 3 without the current hosts) replaces the one of rule 4 when it saves at least
   :data:`MOVE_MARGIN` crossings in all.
"""

from __future__ import annotations

import itertools
from collections import Counter
from collections.abc import Mapping, Set
from dataclasses import dataclass

from ubitrack_agent.net.host_protocol import HostInfo
from ubitrack_agent.net.spec import ComponentSpec, GroupSpec

STATIC_WEIGHT = 0.1
"""The cost of a static input from another host, relative to a stream's."""
LOAD_WEIGHT = 0.5
"""The cost of a fully loaded host, relative to a stream crossing: less than one crossing, so
being near the data always wins over balancing load."""
DOWNSTREAM_WEIGHT = 0.45
"""The cost of a host away from every application reading what a component's derivation
computes: more than a difference of load below 0.9 of the cores (a tie between two hosts on
one loaded machine went by the load each host manager happened to read:
``tests/integration/test_hosts_netns.py``'s fusion on the other host once under a test
suite's load), and with the most load (:data:`LOAD_WEIGHT`) less than a crossing, so that
being near the data still always wins."""
MOVE_MARGIN = 0.75
"""How much cheaper another host must be before a placed component moves there: more than load
and a static input together can make (0.6), less than a stream brought onto the host even
when two static inputs then cross (0.8). The preference for the applications' hosts
(:data:`DOWNSTREAM_WEIGHT`) is not counted here: it chooses where a component starts, and
never moves a running one by itself."""


@dataclass(frozen=True)
class Assignment:
    """The result of :func:`place`: a host for each placed instance, and why the others have
    none (instance -> reason). (Where an instance was started is ``agent.hosts.Placement``.)"""

    hosts: Mapping[str, str]
    unplaced: Mapping[str, str]


def place(
    specs: Mapping[str, ComponentSpec],
    hosts: Mapping[str, HostInfo],
    data_hosts: Mapping[str, str],
    application_hosts: Mapping[str, Set[str]],
    current: Mapping[str, str] | None = None,
    required_labels: Mapping[str, Set[str]] | None = None,
) -> Assignment:
    """A host for every instance of ``specs`` (producers before consumers, as
    ``agent.materialise.component_specs`` orders them), by the rule of the module docstring.

    ``data_hosts`` maps a measured edge's data key to the host of its provider;
    ``application_hosts`` a relation key to the hosts of the applications asking for it;
    ``current`` an instance to the host it runs on now; ``required_labels`` an instance to the
    labels its host must have.
    """
    current = current or {}
    required_labels = required_labels or {}
    downstream = _downstream_hosts(specs, application_hosts)
    kept = _greedy(
        specs, hosts, data_hosts, application_hosts, downstream, current, required_labels
    )
    if not current:
        return kept
    fresh = _greedy(specs, hosts, data_hosts, application_hosts, downstream, {}, required_labels)
    saved = _total_crossings(specs, kept, data_hosts, application_hosts) - _total_crossings(
        specs, fresh, data_hosts, application_hosts
    )
    return fresh if saved >= MOVE_MARGIN else kept


def _greedy(
    specs: Mapping[str, ComponentSpec],
    hosts: Mapping[str, HostInfo],
    data_hosts: Mapping[str, str],
    application_hosts: Mapping[str, Set[str]],
    downstream: Mapping[str, frozenset[str]],
    current: Mapping[str, str],
    required_labels: Mapping[str, Set[str]],
) -> Assignment:
    """Rules 1 to 4 of the module docstring, one component at a time, producers first;
    ``downstream`` is :func:`_downstream_hosts` of ``specs``."""
    origin = dict(data_hosts)  # data key -> host, the outputs of placed components added
    planned = dict.fromkeys(hosts, 0)
    placed: dict[str, str] = {}
    unplaced: dict[str, str] = {}
    for instance, spec in specs.items():
        labels = frozenset(required_labels.get(instance, ()))
        eligible = [
            name
            for name, info in sorted(hosts.items())
            if labels <= info.labels and planned[name] < info.capacity
        ]
        if not eligible:
            unplaced[instance] = _why_none(hosts, labels)
            continue
        costs = {
            name: _crossings(spec, name, origin, application_hosts)
            + LOAD_WEIGHT * _load(hosts[name], planned[name])
            for name in eligible
        }
        readers = downstream[instance]
        best = min(
            eligible,
            key=lambda name: (
                costs[name] + (DOWNSTREAM_WEIGHT if readers and name not in readers else 0.0),
                name,
            ),
        )
        here = current.get(instance)
        if here in costs and costs[here] - costs[best] < MOVE_MARGIN:
            best = here
        placed[instance] = best
        planned[best] += 1
        for key in spec.outputs.values():
            origin[key] = best
    return Assignment(placed, unplaced)


def _total_crossings(
    specs: Mapping[str, ComponentSpec],
    placement: Assignment,
    data_hosts: Mapping[str, str],
    application_hosts: Mapping[str, Set[str]],
) -> float:
    """The streams crossing between hosts under ``placement``, over every placed component
    (an unplaced one counts as one crossing per input and relation: placing more is better)."""
    origin = dict(data_hosts)
    for instance, host in placement.hosts.items():
        origin.update(dict.fromkeys(specs[instance].outputs.values(), host))
    total = 0.0
    for instance, spec in specs.items():
        host = placement.hosts.get(instance)
        if host is None:
            total += len(spec.inputs) + len(spec.relations)
        else:
            total += _crossings(spec, host, origin, application_hosts)
    return total


def _crossings(
    spec: ComponentSpec,
    host: str,
    origin: Mapping[str, str],
    application_hosts: Mapping[str, Set[str]],
) -> float:
    """The streams that would cross between hosts were ``spec`` placed on ``host``."""
    cost = 0.0
    for binding in spec.inputs:
        source = origin.get(binding.key)
        if source is not None and source != host:
            cost += STATIC_WEIGHT if binding.static else 1.0
    for keys in spec.relations.values():
        readers: set[str] = set()
        for key in keys:
            readers |= set(application_hosts.get(key, ()))
        cost += len(readers - {host})
    return cost


def _downstream_hosts(
    specs: Mapping[str, ComponentSpec], application_hosts: Mapping[str, Set[str]]
) -> dict[str, frozenset[str]]:
    """For each instance, the hosts of the applications reading a relation it or a component
    downstream of it publishes; O(components + bindings + relations), consumers seen before
    their producers (``specs`` lists producers first)."""
    readers_of: dict[str, list[str]] = {}
    for instance, spec in specs.items():
        for binding in spec.inputs:
            readers_of.setdefault(binding.key, []).append(instance)
    downstream: dict[str, frozenset[str]] = {}
    for instance in reversed(list(specs)):
        spec = specs[instance]
        hosts: set[str] = set()
        for keys in spec.relations.values():
            for key in keys:
                hosts |= set(application_hosts.get(key, ()))
        for key in spec.outputs.values():
            for reader in readers_of.get(key, ()):
                hosts |= downstream.get(reader, frozenset())
        downstream[instance] = frozenset(hosts)
    return downstream


def _load(info: HostInfo, planned: int) -> float:
    """A host's load in [0, 1]: the share of its capacity taken, or its CPU load per core."""
    return min(1.0, max(planned / info.capacity, info.cpu_load))


def _why_none(hosts: Mapping[str, HostInfo], labels: frozenset[str]) -> str:
    if not hosts:
        return "no host manager is alive"
    if labels and not any(labels <= info.labels for info in hosts.values()):
        return f"no live host manager has the labels {', '.join(sorted(labels))}"
    return "every eligible host manager runs as many workers as its capacity"


def group_containers(
    specs: Mapping[str, ComponentSpec],
    hosts: Mapping[str, str],
    cores: Mapping[str, int],
    isolated: Set[str] = frozenset(),
    isolating_hosts: Set[str] = frozenset(),
    current: Mapping[str, str] | None = None,
) -> dict[str, GroupSpec]:
    """The containers (``ubitrack_agent.services.container``) the placed components of ``specs`` run
    in, by name: the rule of issue 28 ("Placement of groups").

    1. **Derivations stay together**: on each host, the components wired to one another there
       (an input reading another's output key, ``GroupSpec.wires``) form one derivation, and
       a derivation is never split, so a sample crosses no process boundary inside a host.
    2. **One container per core**: a host's derivations share ``cores[host]`` containers (at
       least one) named ``<host>-<k>``; the largest derivation goes first, each into the
       container holding the fewest components so far (ties: the lower ``k``).
    3. **Stable**: a component already running in one of those containers (``current``:
       instance -> container) stays there, so a change of plan moves nothing (a move would
       stop and start it, losing its state); the new components of a derivation that runs
       go to the container holding most of its components (ties: the name first in order).
    4. **Isolation**: an instance in ``isolated`` (its template asks for it: a real camera
       adapter, OpenCV-heavy or untrusted code), and every component of a host in
       ``isolating_hosts``, runs alone in ``<host>-<instance>``.
    5. **Copies apart**: derivations that put on one relation key (a relation's derivation,
       its spares and replicas: ``agent.spares``) go into different containers (rule 2 among
       those holding none of its keys), so the death of one process leaves a copy computing;
       where the host's containers all hold one, another is opened (``<host>-<cores>``, ...;
       the one the derivation runs in already, if any: rule 3).
       A derivation sharing a component with another is one derivation (rule 1).

    ``hosts`` maps a placed instance to its host (:attr:`Assignment.hosts`); unplaced
    instances are left out. Pure and deterministic; O(components + bindings) per host, plus
    O(derivations x containers) for rules 2 and 5.
    """
    current = current or {}
    groups: dict[str, list[ComponentSpec]] = {}
    for host in sorted(set(hosts.values())):
        here = [spec for instance, spec in specs.items() if hosts.get(instance) == host]
        shared = []
        for spec in here:
            if host in isolating_hosts or spec.instance in isolated:
                groups[f"{host}-{spec.instance}"] = [spec]
            else:
                shared.append(spec)
        count = max(1, cores.get(host, 1))
        containers = [f"{host}-{k}" for k in range(count)]
        filled: dict[str, list[ComponentSpec]] = {name: [] for name in containers}
        publishing: dict[str, set[str]] = {name: set() for name in containers}
        """The relation keys each container's components put on (rule 5)."""
        extra: list[str] = []
        """Containers opened by rule 5."""
        pending = []
        for derivation in _derivations(shared):
            running = Counter(
                name for spec in derivation if (name := current.get(spec.instance)) in filled
            )
            if not running:
                pending.append(derivation)
                continue
            home = min(running, key=lambda name: (-running[name], name))
            for spec in derivation:
                name = current[spec.instance] if current.get(spec.instance) in filled else home
                filled[name].append(spec)
                publishing[name].update(_relation_keys([spec]))
        for derivation in sorted(pending, key=len, reverse=True):  # stable: ties keep order
            keys = _relation_keys(derivation)
            apart = [name for name in containers if not keys & publishing[name]] or [
                name for name in extra if not keys & publishing[name]
            ]
            if not apart:
                apart = [_another_container(host, count, derivation, current, filled)]
                extra.append(apart[0])
                filled[apart[0]], publishing[apart[0]] = [], set()
            emptiest = min(apart, key=lambda name: (len(filled[name]), name))
            filled[emptiest].extend(derivation)
            publishing[emptiest].update(keys)
        groups.update({name: members for name, members in filled.items() if members})
    order = {instance: index for index, instance in enumerate(specs)}
    return {
        name: GroupSpec(name, tuple(sorted(members, key=lambda spec: order[spec.instance])))
        for name, members in groups.items()
    }


def _another_container(
    host: str,
    cores: int,
    derivation: list[ComponentSpec],
    current: Mapping[str, str],
    taken: Mapping[str, object],
) -> str:
    """The container rule 5 opens for ``derivation``: one beyond the host's ``cores`` it runs
    in already (rule 3), else the first such name not ``taken``."""
    running = sorted({current.get(spec.instance) for spec in derivation} - {None})
    for name in running:
        suffix = name.removeprefix(f"{host}-")
        if name != suffix and suffix.isdigit() and int(suffix) >= cores and name not in taken:
            return name
    return next(f"{host}-{k}" for k in itertools.count(cores) if f"{host}-{k}" not in taken)


def _relation_keys(specs: list[ComponentSpec]) -> set[str]:
    """The relation keys ``specs`` put on."""
    return {key for spec in specs for keys in spec.relations.values() for key in keys}


def _derivations(specs: list[ComponentSpec]) -> list[list[ComponentSpec]]:
    """``specs`` split into the sets wired to one another (connected by an input reading
    another's output key), each in the order of ``specs``; union-find, O(bindings)."""
    parent = list(range(len(specs)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    producer = {key: i for i, spec in enumerate(specs) for key in spec.outputs.values()}
    for i, spec in enumerate(specs):
        for binding in spec.inputs:
            j = producer.get(binding.key)
            if j is not None:
                parent[root(i)] = root(j)
    sets: dict[int, list[ComponentSpec]] = {}
    for i, spec in enumerate(specs):
        sets.setdefault(root(i), []).append(spec)
    return list(sets.values())
