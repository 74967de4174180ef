"""Data flow components into worker specifications (``services.spec.ComponentSpec``).

* A port ``IF[2]`` of a space-expanded component is the third binding of port ``IF``.
* An input bound to a measured edge ``<provider>/<name>`` reads that edge's data key; an input
  bound to a component's output reads ``<root>/data/<component>/<output>``.
* An input is ``static`` if its edge is: a measured edge by its announcement; a component's
  output as the planner decided (``Component.static_outputs``).
* Every dynamic input triggers (each instant is computed once, ``services.triggers``); a
  component whose inputs are all static recomputes whenever one of them changes.
* The producer of a queried relation also publishes on the relation's stable key; a relation
  answered by a measured edge as it is gets a ``relay`` component.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Set
from dataclasses import replace
from typing import Protocol

import networkx as nx

from ubitrack_agent.graph.dataflow import Binding, DataFlow
from ubitrack_agent.graph.srg import edge_ids
from ubitrack_agent.net.keys import RelationId
from ubitrack_agent.net.spec import (
    ComponentSpec,
    InputBinding,
    before_port,
    parse_before_port,
    parse_then_port,
    then_port,
)


def _port(name: str) -> str:
    return name.split("[", 1)[0]


def _measured_static(srg: nx.MultiDiGraph, edge_id: str) -> bool:
    source, target = edge_ids(srg)[edge_id]
    return bool(srg.edges[source, target, edge_id]["static"])


class Keys(Protocol):
    """The keys a specification names: :class:`~ubitrack_agent.net.keys.KeySpace`'s, or, to
    place a plan offline (``ubitrack plan --host``), any strings telling the streams apart."""

    def data(self, edge_id: str) -> str: ...

    def relation(self, relation: RelationId) -> str: ...


def component_specs(
    flow: DataFlow,
    srg: nx.MultiDiGraph,
    keys: Keys,
    relations: Mapping[str, RelationId],
) -> dict[str, ComponentSpec]:
    """The worker specification of every component of ``flow``, by instance id."""
    specs: dict[str, ComponentSpec] = {}

    def source(binding: Binding) -> tuple[str, bool, bool]:
        """The key, whether it is static, and whether a worker produces it."""
        if binding.component is None:
            return keys.data(binding.edge), _measured_static(srg, binding.edge), False
        producer = flow.components[binding.component]
        static = binding.edge in producer.static_outputs
        return keys.data(f"{producer.id}/{binding.edge}"), static, True

    for component in flow.components.values():  # producers come before their consumers
        sources = [(port, *source(binding)) for port, binding in component.inputs]
        dynamic = not all(static for _, _, static, _ in sources)
        bindings = tuple(
            InputBinding(
                _port(port),
                key,
                trigger=not static or not dynamic,
                static=static,
                from_worker=from_worker,
            )
            for port, key, static, from_worker in sources
        )
        specs[component.id] = ComponentSpec(
            instance=component.id,
            service=component.service,
            inputs=bindings,
            outputs={name: keys.data(f"{component.id}/{name}") for name, *_ in component.outputs},
            parameters=dict(component.parameters),
            expansion=component.expansion,
        )
    for name, binding in flow.relations.items():
        relation_key = keys.relation(relations[name])
        if binding.component is not None:
            spec = specs[binding.component]
            routes = dict(spec.relations)
            routes[binding.edge] = (*routes.get(binding.edge, ()), relation_key)
            specs[binding.component] = replace(spec, relations=routes)
            continue
        key, static, from_worker = source(binding)
        instance = "relay-" + hashlib.sha1(binding.edge.encode()).hexdigest()[:10]
        specs[instance] = ComponentSpec(
            instance=instance,
            service="relay",
            inputs=(InputBinding("in", key, True, static, from_worker=from_worker),),
            outputs={"out": keys.data(f"{instance}/out")},
            relations={"out": (relation_key,)},
        )
    return specs


def fold(
    specs: Mapping[str, ComponentSpec], keep: Set[str] = frozenset()
) -> tuple[dict[str, ComponentSpec], dict[str, str]]:
    """``specs`` with the components that need no hop of their own folded into a neighbour
    (:func:`fold_static_compositions`, then :func:`fold_inversions`; none in ``keep``), and the
    component each folded one now runs in."""
    specs, folded = fold_static_compositions(specs, keep)
    specs, inversions = fold_inversions(specs, keep)
    folded = {instance: inversions.get(into, into) for instance, into in folded.items()}
    return specs, {**folded, **inversions}


def fold_static_compositions(
    specs: Mapping[str, ComponentSpec], keep: Set[str] = frozenset()
) -> tuple[dict[str, ComponentSpec], dict[str, str]]:
    """``specs`` with every concatenation of a static edge with a worker's output that nothing
    else reads folded into that worker, and which component each folded one went into.

    Such a concatenation costs the flow a hop (a process woken, a message decoded, composed,
    encoded, published) for a product with a value that seldom changes: its producer composes
    its output with the static edge before publishing instead (``net.spec.then_port``), on the
    concatenation's own output key, so its consumers and relation routes are unchanged. A chain
    folds into its first producer: the A.R.T. path of the paper's figure 6 (an inversion, then
    two concatenations with calibrations) becomes one hop, and the last hop after the fusion
    goes into the fusion. Folded: a concatenation (not in ``keep``) whose one input is static
    and whose other is a dynamic worker output that no other component reads and no relation
    is published on; specifications are taken in order, producers before their consumers
    (so a folded concatenation's producer is never folded itself afterwards).
    """
    specs = dict(specs)
    folded: dict[str, str] = {}
    for instance in list(specs):
        spec = specs[instance]
        if instance in keep or spec.service != "concatenation" or len(spec.inputs) != 2:
            continue
        static = [binding for binding in spec.inputs if binding.static]
        dynamic = [binding for binding in spec.inputs if not binding.static]
        if len(static) != 1 or len(dynamic) != 1 or not dynamic[0].from_worker:
            continue
        if dynamic[0].clock_offset_ns:
            continue  # its producer's output moved to another clock: not the producer's value
        producer = _producer(specs, dynamic[0].key)
        if producer is None or len(_readers(specs, dynamic[0].key)) != 1:
            continue
        host, port = producer
        into = specs[host]
        if into.relations.get(port):
            continue
        order = sum(
            (then := parse_then_port(binding.port)) is not None and then[0] == port
            for binding in into.inputs
        )
        edge = replace(static[0], port=then_port(port, order, static[0].port), trigger=False)
        routes = dict(into.relations)
        if spec.relations.get("AC"):
            routes[port] = spec.relations["AC"]
        specs[host] = replace(
            into,
            inputs=(*into.inputs, edge),
            outputs={**into.outputs, port: spec.outputs["AC"]},
            relations=routes,
        )
        del specs[instance]
        folded[instance] = host
    return specs, folded


def fold_inversions(
    specs: Mapping[str, ComponentSpec], keep: Set[str] = frozenset()
) -> tuple[dict[str, ComponentSpec], dict[str, str]]:
    """``specs`` with every inversion of a dynamic edge whose output one other component's
    input reads (and no relation is published on) folded into that component, and which
    component each folded one went into.

    The reading input then reads the inversion's input key, ``inverted``, and takes the
    static edges the inversion's output was composed with (:func:`fold_static_compositions`)
    as its own (``net.spec.before_port``): the same value, computed by the same services in
    the reader's process, one hop (a process woken, a message decoded, encoded, published)
    fewer. With the A.R.T. path of the paper's figure 6 folded into the fusion, a fused pose
    passes as many workers as one from the A.R.T. path alone (issue 12). Not folded: an
    inversion in ``keep``, or read by an input that is itself static, composed, inverted or in
    ``keep``'s component."""
    specs = dict(specs)
    folded: dict[str, str] = {}
    for instance in list(specs):
        spec = specs[instance]
        if instance in keep or spec.service != "inversion" or spec.relations.get("BA"):
            continue
        sources = [binding for binding in spec.inputs if parse_then_port(binding.port) is None]
        if len(sources) != 1 or sources[0].static or sources[0].inverted:
            continue
        readers = _readers(specs, spec.outputs["BA"])
        if len(readers) != 1 or readers[0][0] in keep:
            continue
        reader, index = readers[0]
        into = specs[reader]
        binding = into.inputs[index]
        if binding.static or binding.inverted or binding.port not in _service_ports(into):
            continue
        source = sources[0]
        inverted = replace(
            binding,
            key=source.key,
            clock_offset_ns=source.clock_offset_ns,
            from_worker=source.from_worker,
            inverted=True,
        )
        thens = [(then, edge) for edge in spec.inputs if (then := parse_then_port(edge.port))]
        composed = [  # in turn, as the inversion composed its output
            replace(edge, port=before_port(index, order, side))
            for (_, order, side), edge in sorted(thens, key=lambda pair: pair[0][1])
        ]
        inputs = (*into.inputs[:index], inverted, *into.inputs[index + 1 :], *composed)
        specs[reader] = replace(into, inputs=inputs)
        del specs[instance]
        folded[instance] = reader
    return specs, folded


def _service_ports(spec: ComponentSpec) -> set[str]:
    """The ports of ``spec``'s inputs that are its service's (not a composed edge's)."""
    return {
        binding.port
        for binding in spec.inputs
        if parse_then_port(binding.port) is None and parse_before_port(binding.port) is None
    }


def _producer(specs: Mapping[str, ComponentSpec], key: str) -> tuple[str, str] | None:
    """The instance and output port publishing data on ``key``."""
    for instance, spec in specs.items():
        for port, output in spec.outputs.items():
            if output == key:
                return instance, port
    return None


def _readers(specs: Mapping[str, ComponentSpec], key: str) -> list[tuple[str, int]]:
    """The inputs reading ``key``: each its instance and its index in the instance's inputs."""
    return [
        (instance, index)
        for instance, spec in specs.items()
        for index, binding in enumerate(spec.inputs)
        if binding.key == key
    ]
