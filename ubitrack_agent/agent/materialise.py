"""Data flow components into worker specifications (``ubitrack_agent.services.spec.ComponentSpec``).

* A port ``IF[2]`` of a space-expanded component is the third binding of port ``IF``.
* An input bound to a measured edge ``<provider>/<name>`` reads that edge's data key; an input
  bound to a component's output reads ``<root>/data/<component>/<output>``.
* An input is ``static`` if its edge is: a measured edge by its announcement; a component's
  output as the planner decided (``Component.static_outputs``). A static input's error is
  *fixed* (``InputBinding.fixed_error``: its covariance marked static for a fusion to
  consider) if it is a measured edge given without a rate, or a static output of a time
  expansion or of a component whose inputs are all fixed.
* Every dynamic input triggers (each instant is computed once,
``ubitrack_agent.services.triggers``); a
  component whose inputs are all static recomputes whenever one of them changes.
* The producer of a queried relation also publishes on the relation's stable key, and so does
  each spare producer of it (``agent.spares``; the hand-over decides which one puts,
  ``services.handover``); a relation answered by a measured edge as it is gets a ``relay``
  component.
* Each component names the providers and the measured edges it needs
  (``ComponentSpec.required_providers``, ``required_edges``; :func:`required_inputs`): when
  one of them leaves or stops delivering, a producer of a relation key gives the key up at once
  (``services.handover``, rule 7) instead of falling quiet.
* Each component of the flow (each step of a pattern, Pustka et al. 2006, section 5) is one
  specification: the components of a derivation on one host run in one container
  (``agent.placement.group_containers``), where they hand each other their outputs as
  objects, so no step needs merging into another to save a hop.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from dataclasses import replace
from typing import NamedTuple, Protocol

import networkx as nx

from ubitrack_agent.graph.dataflow import Binding, DataFlow
from ubitrack_agent.graph.srg import edge_ids
from ubitrack_agent.net.keys import RelationId
from ubitrack_agent.net.spec import ComponentSpec, InputBinding


def _port(name: str) -> str:
    return name.split("[", 1)[0]


def _measured_static(srg: nx.MultiDiGraph, edge_id: str) -> tuple[bool, bool]:
    """Whether a measured edge is static, and whether its error is fixed: static and given
    without a rate (a calibration, a survey), not measured again at one (a tracker's static
    body)."""
    source, target = edge_ids(srg)[edge_id]
    data = srg.edges[source, target, edge_id]
    static = bool(data["static"])
    return static, static and not data["quality"].rate > 0


class Keys(Protocol):
    """The keys a specification names: :class:`~ubitrack_agent.net.keys.KeySpace`'s, or, to
    place a plan offline (``ubitrack plan --host``), any strings telling the streams apart."""

    def data(self, edge_id: str) -> str: ...

    def relation(self, relation: RelationId) -> str: ...


def relay_instance(edge_id: str) -> str:
    """The instance of the relay putting the measured edge ``edge_id`` on a relation key."""
    return "relay-" + hashlib.sha1(edge_id.encode()).hexdigest()[:10]


class Need(NamedTuple):
    """What a component cannot compute anything new without: a provider (``kind``
    ``"provider"``, ``name`` its id: its liveliness token) or one of its measured edges
    (``"edge"``, ``name`` the edge's id: the token on its data key while it delivers)."""

    kind: str
    name: str


def _edge_needs(srg: nx.MultiDiGraph, edge_id: str) -> frozenset[Need]:
    """A dynamic measured edge needs itself and its provider (a static one nothing: its value
    is kept)."""
    source, target = edge_ids(srg)[edge_id]
    data = srg.edges[source, target, edge_id]
    if data["static"]:
        return frozenset()
    return frozenset({Need("provider", data["provider"]), Need("edge", edge_id)})


def required_inputs(flow: DataFlow, srg: nx.MultiDiGraph) -> dict[str, frozenset[Need]]:
    """The providers and measured edges each component of ``flow`` needs to compute anything
    new, by component id: the dynamic measured edges it reads and their providers, and those
    its dynamic inputs' producers need. Of the several bindings of one port (a space
    expansion: the estimates a fusion combines, the correspondences of a pose estimation) only
    what *every* binding needs counts, since such a component computes on with the bindings
    left: a fusion with one tracker gone needs nothing, a pose estimation from five features of
    one camera needs the camera but no single feature. A static input (a calibration, a
    survey, a time expansion's result) needs nothing: it is kept. Producers come before their
    consumers in ``flow``, so one pass: O(bindings x needs).

    A provider leaving, or an edge that stops delivering, is known at once from a liveliness
    token (the provider's; its token on the edge's data key, withdrawn when the provider leaves
    or at the adapter after two and a half of the edge's intervals without a sample,
    ``io.flowing``), while the relation key falls quiet only after three of the holder's
    intervals (``services.handover``, rule 7: a producer that needs it gives its relation keys
    up then)."""
    needed: dict[str, frozenset[Need]] = {}
    for component in flow.components.values():
        by_port: dict[str, list[frozenset[Need]]] = {}
        for port, binding in component.inputs:
            if binding.component is None:
                needs = _edge_needs(srg, binding.edge)
            elif binding.edge in flow.components[binding.component].static_outputs:
                needs = frozenset()
            else:
                needs = needed[binding.component]
            by_port.setdefault(_port(port), []).append(needs)
        needed[component.id] = frozenset().union(
            *(frozenset.intersection(*sets) for sets in by_port.values())
        )
    return needed


def _required(needs: frozenset[Need], keys: Keys) -> dict[str, tuple[str, ...]]:
    """A specification's fields naming ``needs``: provider ids, and the edges' data keys."""
    return {
        "required_providers": tuple(sorted(n.name for n in needs if n.kind == "provider")),
        "required_edges": tuple(sorted(keys.data(n.name) for n in needs if n.kind == "edge")),
    }


def component_specs(
    flow: DataFlow,
    srg: nx.MultiDiGraph,
    keys: Keys,
    relations: Mapping[str, RelationId],
) -> dict[str, ComponentSpec]:
    """The worker specification of every component of ``flow``, by instance id (producers
    before their consumers, then the relays). O(components + bindings + relations)."""
    specs: dict[str, ComponentSpec] = {}
    needed = required_inputs(flow, srg)
    fixed_outputs: set[str] = set()
    """The components whose static outputs have a fixed error: estimated over time (a
    calibration), or computed from fixed inputs alone."""

    def source(binding: Binding) -> tuple[str, bool, bool, bool]:
        """The key, whether it is static, whether its error is fixed, and whether a worker
        produces it."""
        if binding.component is None:
            return keys.data(binding.edge), *_measured_static(srg, binding.edge), False
        producer = flow.components[binding.component]
        static = binding.edge in producer.static_outputs
        fixed = static and producer.id in fixed_outputs
        return keys.data(f"{producer.id}/{binding.edge}"), static, fixed, True

    for component in flow.components.values():  # producers come before their consumers
        sources = [(port, *source(binding)) for port, binding in component.inputs]
        dynamic = not all(static for _, _, static, _, _ in sources)
        if component.expansion == "time" or all(fixed for *_, fixed, _ in sources):
            fixed_outputs.add(component.id)
        bindings = tuple(
            InputBinding(
                _port(port),
                key,
                trigger=not static or not dynamic,
                static=static,
                from_worker=from_worker,
                fixed_error=fixed,
            )
            for port, key, static, fixed, from_worker in sources
        )
        specs[component.id] = ComponentSpec(
            instance=component.id,
            service=component.service,
            inputs=bindings,
            outputs={name: keys.data(f"{component.id}/{name}") for name, *_ in component.outputs},
            parameters=dict(component.parameters),
            expansion=component.expansion,
            **_required(needed[component.id], keys),
        )
    producers = [(name, b) for name, bs in flow.spares.items() for b in bs]
    for name, binding in [*flow.relations.items(), *producers]:
        relation_key = keys.relation(relations[name])
        if binding.component is not None:
            spec = specs[binding.component]
            routes = dict(spec.relations)
            known = routes.get(binding.edge, ())
            routes[binding.edge] = known if relation_key in known else (*known, relation_key)
            specs[binding.component] = replace(spec, relations=routes)
            continue
        key, static, _, from_worker = source(binding)
        instance = relay_instance(binding.edge)
        specs[instance] = ComponentSpec(
            instance=instance,
            service="relay",
            inputs=(InputBinding("in", key, True, static, from_worker=from_worker),),
            outputs={"out": keys.data(f"{instance}/out")},
            relations={"out": (relation_key,)},
            **_required(_edge_needs(srg, binding.edge), keys),
        )
    return specs
