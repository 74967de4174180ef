"""Data flow graphs built from planned solutions and shared between queries (section 5.1).

"When an expanded instance of pattern P_i is applied in the SR graph, this creates a new
component in the data flow graph [...] The inputs of the component are connected to the
components associated with the matched input edges." A :class:`DataFlow` is that graph: one
:class:`Component` per applied pattern instance, each input port bound either to a measured SRG
edge or to an output of another component, plus the *relations* the applications asked for.

Component ids name the whole computation (template, expansion, the relations read and
written, and the producer of each input: :func:`from_solution`), so the same computation planned
for two queries gets the same id (sharing, section 5.1 "Data flow construction"), and a
component whose upstream changed is another component, started beside the old one (make
before break).

Besides the producer bound to each relation, a flow may name *spare* producers of it (the
derivations the agent runs beside the chosen one for the loss of a sensor, and replicas of the
chosen one for the loss of its process: ``agent.spares``).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import networkx as nx

from ubitrack_agent.graph.planner import PlanningError, Query, Solution, plan
from ubitrack_agent.graph.templates import Template


@dataclass(frozen=True)
class Binding:
    """Where an input reads from: ``component`` is ``None`` for a measured SRG edge (``edge`` is
    its edge id), otherwise the producing component id and ``edge`` its output name."""

    component: str | None
    edge: str

    def as_json(self) -> list[str | None]:
        return [self.component, self.edge]


@dataclass(frozen=True)
class Component:
    """One component instance: a registered ``service`` running ``pattern``.

    ``inputs`` are ``(port, binding)`` pairs, ports named after the template's input edges
    (``IF[0]``, ``IF[1]``... for the copies of a space expansion); ``outputs`` are
    ``(name, from, to, type)``; ``static_outputs`` names the outputs whose edges are static,
    as the matcher decided when it applied the pattern (``matcher.instance_outputs``: declared
    by the template, or inherited, and always for a time expansion, section 3.3).
    """

    id: str
    service: str
    pattern: str
    template: str
    expansion: str
    parameters: Mapping[str, Any]
    inputs: tuple[tuple[str, Binding], ...]
    outputs: tuple[tuple[str, str, str, str], ...]
    static_outputs: frozenset[str] = frozenset()

    def as_json(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "service": self.service,
            "pattern": self.pattern,
            "template": self.template,
            "expansion": self.expansion,
            "parameters": dict(self.parameters),
            "inputs": {port: b.as_json() for port, b in self.inputs},
            "outputs": {name: [src, dst, typ] for name, src, dst, typ in self.outputs},
            "static_outputs": sorted(self.static_outputs),
        }


@dataclass(frozen=True)
class DataFlow:
    """Components by id and the queried relations (``"C->A:6D"``) bound to their producers;
    ``spares``: producers of a relation that stand by (module docstring), by relation name."""

    components: Mapping[str, Component] = field(default_factory=dict)
    relations: Mapping[str, Binding] = field(default_factory=dict)
    spares: Mapping[str, tuple[Binding, ...]] = field(default_factory=dict)

    def as_json(self) -> dict[str, Any]:
        data = {
            "components": [c.as_json() for c in self.components.values()],
            "relations": {name: b.as_json() for name, b in self.relations.items()},
        }
        if self.spares:
            data["spares"] = {n: [b.as_json() for b in bs] for n, bs in self.spares.items()}
        return data


def relation_name(query: Query) -> str:
    """The name of a queried relation, e.g. ``"C->A:6D"`` (``"C->HT:6D/static"`` if static)."""
    suffix = "/static" if query.static else ""
    return f"{query.source}->{query.target}:{query.type}{suffix}"


def _component_id(
    template: str, expansion: str, reads: list[Any], writes: list[Any], replica: int = 0
) -> str:
    named = (template, expansion, reads, writes, *((replica,) if replica else ()))
    digest = hashlib.sha1(repr(named).encode()).hexdigest()[:10]
    return f"{template}-{digest}"


def from_solution(solution: Solution, query: Query, replica: int = 0) -> DataFlow:
    """The data flow graph of one solution (section 5.1, "Data flow construction").

    A component's id names its whole computation, as a Merkle tree does (Merkle 1987): its
    template, expansion and output relations, and for each input the relation and where it is
    read, a measured edge's id or the id of the component producing it. The same computation
    gets the same id in every plan, so the agent finds it running and leaves it as it is; a
    component whose inputs come from another derivation is another component, started beside
    the old one, which keeps working until the new one has taken over (make before break,
    ``services.handover``), and can serve again if its derivation comes back
    (``agent.standby``). ``replica`` k > 0 names the same computation again under other ids:
    the k-th replica of the derivation, which runs beside it (``agent.spares``, "Replicas").
    O(steps x inputs) per solution."""
    records = solution.records
    producer: dict[str, Binding] = {}
    components: dict[str, Component] = {}
    for step in solution.steps:
        reads = [
            (
                name,
                [
                    (
                        records[e].source,
                        records[e].target,
                        records[e].type,
                        producer.get(e, Binding(None, e)).as_json(),
                    )
                    for e in ids
                ],
            )
            for name, ids in step.inputs
        ]
        writes = [(src, dst, typ) for _, src, dst, typ, _ in step.outputs]
        cid = _component_id(step.template.name, step.expansion, reads, writes, replica)
        inputs = []
        for name, ids in step.inputs:
            for k, edge_id in enumerate(ids):
                port = name if len(ids) == 1 else f"{name}[{k}]"
                inputs.append((port, producer.get(edge_id, Binding(None, edge_id))))
        for name, _, _, _, edge_id in step.outputs:
            if edge_id is not None:
                producer[edge_id] = Binding(cid, name)
        components[cid] = Component(
            id=cid,
            service=step.template.service,
            pattern=step.template.pattern,
            template=step.template.name,
            expansion=step.expansion,
            parameters=dict(step.template.parameters),
            inputs=tuple(inputs),
            outputs=tuple((name, src, dst, typ) for name, src, dst, typ, _ in step.outputs),
            static_outputs=frozenset(
                name
                for name, *_, edge_id in step.outputs
                if edge_id is not None and records[edge_id].static
            ),
        )
    final = producer.get(solution.edge.id, Binding(None, solution.edge.id))
    return DataFlow(components, {relation_name(query): final})


def _rebind(binding: Binding, renamed: Mapping[str, str]) -> Binding:
    if binding.component in renamed:
        return Binding(renamed[binding.component], binding.edge)
    return binding


def merge(flows: Iterable[DataFlow]) -> DataFlow:
    """One data flow serving every query of ``flows``; equal components are shared (run once).

    Two flows may compute the same relations from different producers (a component with the
    same id but other input bindings); the later one is then kept under a derived id and its
    consumers are rebound to it, so each flow's computation stays intact. The spare producers
    of a relation are gathered from every flow, each once.
    """
    components: dict[str, Component] = {}
    relations: dict[str, Binding] = {}
    spares: dict[str, tuple[Binding, ...]] = {}
    for flow in flows:
        renamed: dict[str, str] = {}
        for component in flow.components.values():  # producers come before their consumers
            inputs = tuple((port, _rebind(b, renamed)) for port, b in component.inputs)
            component = replace(component, inputs=inputs)
            existing = components.get(component.id)
            if existing is not None and existing != component:
                new_id = _component_id(component.id, component.expansion, [], [repr(inputs)])
                renamed[component.id] = new_id
                component = replace(component, id=new_id)
            components[component.id] = component
        relations.update({name: _rebind(b, renamed) for name, b in flow.relations.items()})
        for name, bindings in flow.spares.items():
            known = spares.get(name, ())
            spares[name] = known + tuple(
                b for b in (_rebind(b, renamed) for b in bindings) if b not in known
            )
    return DataFlow(components, relations, spares)


def best(query: Query, solutions: Sequence[Solution]) -> Solution:
    """The planner's choice: the cheapest solution."""
    return solutions[0]


def plan_flows(
    srg: nx.MultiDiGraph,
    templates: Sequence[Template],
    queries: Iterable[Query],
    choose: Callable[[Query, Sequence[Solution]], Solution] = best,
) -> tuple[DataFlow, dict[str, str]]:
    """Plan every query on ``srg`` and merge the chosen data flows (shared components).

    ``choose`` picks one of a query's solutions (cheapest first); by default the cheapest.
    Returns the data flow and, for each query that has no solution now, its relation name and
    the reason, so that the caller can keep serving the others (the live agent replans when
    the SRG changes and reconciles its workers with the result).
    """
    flows, unresolved = [], {}
    for query in queries:
        try:
            flows.append(from_solution(choose(query, plan(srg, templates, query)), query))
        except PlanningError as exc:
            unresolved[relation_name(query)] = str(exc)
    return merge(flows), unresolved
