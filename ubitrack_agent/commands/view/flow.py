"""The live data flow as a graph: nodes, wires and groups, in the style of the paper's figure 6
(Pustka et al. 2006, section 5: providers feed components, one per step of a pattern, which
feed the applications' relations). One description, two drawings: the page lays it out in the
browser with dagre (``/flow.json``, ``view.js``), and :func:`flow_dot` writes it as Graphviz
DOT (``/flow.dot``, ``/flow.svg``, ``ubitrack status --dot``).

* a **provider** (a source) per announcing provider;
* a **component** per running component: its pattern (or service), instance and host (in a
  group, the group names the host); grey while starting;
* an **application** (a sink) per served relation, named with the applications asking for it;
* a **key** for an input read from a key no provider or component announces;
* a **group** per container: the components a container runs together (one process handing
  each other their outputs as objects, ``agent.placement.group_containers``) are drawn inside
  one box naming the container and its host, so a group shows its parts;
* a **wire** from producer to consumer, labelled with the type it carries, its rate and the
  latency its consumer measures (:func:`wire_latency_ms`); ``static`` when the consumer reads
  it as a static edge (drawn dashed).

O(providers' edges + components' inputs + relations x components) per status.
"""

from __future__ import annotations

from typing import Any

from ubitrack_agent.graph.dot import quote


def flow_graph(status: dict[str, Any], rates: dict[str, float] | None = None) -> dict[str, Any]:
    """The flow of ``status`` (the agent's, as ``ubitrack status --json`` gives it) as
    ``{"nodes": [...], "wires": [...], "groups": [...]}``; a node is ``{"id", "kind", "lines",
    "alive", "group"}``, a wire ``{"from", "to", "label", "static"}``, a group ``{"id",
    "lines"}``. ``rates`` holds each component's measured output rate (Hz), by instance.
    Raises KeyError, TypeError, AttributeError or ValueError on a status of another shape."""
    rates = rates or {}
    data = f"{status['key_prefix']}/data/"
    edges = {edge["id"]: edge for edge in status.get("srg", [])}
    nodes: list[dict[str, Any]] = []
    wires: list[dict[str, Any]] = []
    groups: dict[str, dict[str, Any]] = {}
    producers: dict[str, tuple[str, str]] = {}  # key -> (node, wire label)
    for provider, edge_ids in status.get("providers", {}).items():
        node = f"provider {provider}"
        nodes.append(_node(node, "provider", [provider]))
        for edge_id in edge_ids:
            edge = edges.get(edge_id, {})
            rate = edge.get("rate") or 0.0
            label = edge.get("type", "?") + (" static" if edge.get("static") else "")
            label += f", {rate:g} Hz" if rate else ""
            producers[data + edge_id] = (node, label)
    components = status.get("components", {})
    for instance, component in components.items():
        group = component.get("container") or None
        if group is not None and group not in groups:
            host = component.get("host")
            groups[group] = {"id": group, "lines": [f"container {group}"]}
            if host:
                groups[group]["lines"].append(f"on {host}")
        # in a group, the group's box names the container and its host
        where = [f"on {component['host']}"] if component.get("host") and not group else []
        name = component.get("pattern") or component["service"]
        alive = bool(component.get("alive"))
        nodes.append(_node(instance, "component", [name, instance, *where], alive, group))
        kinds = {typ for _, _, typ in component.get("derives", [])}
        kind = kinds.pop() if len(kinds) == 1 else "?"
        rate = f", {rates[instance]:.0f} Hz" if instance in rates else ""
        for key in component.get("outputs", {}).values():
            producers[key] = (instance, kind + rate)
    for instance, component in components.items():
        for binding in component.get("inputs", []):
            node, label = producers.get(binding["key"], (binding["key"], "?"))
            if binding["key"] not in producers:
                nodes.append(_node(node, "key", [node]))
            latency = wire_latency_ms(status, component, binding)
            label += f", {latency:.0f} ms" if latency is not None else ""
            wires.append(_wire(node, instance, label, bool(binding.get("static"))))
    for name, relation in status.get("relations", {}).items():
        sink = f"application {name}"
        nodes.append(_node(sink, "application", [*status.get("queries", {}).get(name, []), name]))
        for instance, component in components.items():
            routes = component.get("relations", {}).values()
            if any(relation["key"] in keys for keys in routes):
                _, wire = producers.get(next(iter(component["outputs"].values()), ""), ("", ""))
                wires.append(_wire(instance, sink, wire, name.endswith("/static")))
    return {"nodes": _unique(nodes), "wires": wires, "groups": list(groups.values())}


def _node(
    node_id: str,
    kind: str,
    lines: list[str],
    alive: bool = True,
    group: str | None = None,
) -> dict[str, Any]:
    return {"id": node_id, "kind": kind, "lines": lines, "alive": alive, "group": group}


def _wire(source: str, target: str, label: str, static: bool) -> dict[str, Any]:
    return {"from": source, "to": target, "label": label, "static": static}


def _unique(nodes: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The nodes, each id once (the first): a key read by two components is one node."""
    seen: dict[str, dict[str, Any]] = {}
    for node in nodes:
        seen.setdefault(node["id"], node)
    return list(seen.values())


def wire_latency_ms(
    status: dict[str, Any], component: dict[str, Any], binding: dict[str, Any]
) -> float | None:
    """The latency (ms) of the samples ``component`` takes on its input ``binding``, as its
    worker measures it (``latency_ms``: its host's clock minus the samples' timestamps), put
    on the agent's clock when the input's timestamps are (a ``clock_offset_ns`` set: add the
    worker's host's offset, ``host_info``); None if not known."""
    latency = component.get("latency_ms", {}).get(binding["key"])
    if latency is None:
        return None
    if binding.get("clock_offset_ns"):
        info = status.get("host_info", {}).get(component.get("host")) or {}
        clock = info.get("clock")
        if not clock:
            return None  # on another clock than its worker's, by an offset not known here
        latency += clock["offset_ns"] / 1e6
    return latency


SHAPES = {"provider": "house", "component": "box", "application": "invhouse", "key": "plaintext"}
"""Graphviz's shape of each kind of node (figure 6: sources, components, sinks)."""


def flow_dot(status: dict[str, Any], rates: dict[str, float] | None = None) -> str:
    """DOT of :func:`flow_graph`: containers as clusters, static wires dashed, starting
    components grey."""
    graph = flow_graph(status, rates)
    lines = [f"digraph {quote(status['key_prefix'])} {{", "  rankdir=LR;"]
    members: dict[str, list[str]] = {group["id"]: [] for group in graph["groups"]}
    for node in graph["nodes"]:
        attributes = f"shape={SHAPES[node['kind']]}"
        if node["kind"] == "component":
            colour = "black" if node["alive"] else "grey"
            attributes += f", color={colour}, fontcolor={colour}"
        line = f"{quote(node['id'])} [{attributes}, label={quote(chr(10).join(node['lines']))}];"
        if node["group"] is None:
            lines.append(f"  {line}")
        else:
            members[node["group"]].append(line)
    for number, group in enumerate(graph["groups"]):
        lines.append(f"  subgraph cluster_{number} {{")
        lines.append(f"    label={quote(chr(10).join(group['lines']))}; style=dashed;")
        lines.extend(f"    {line}" for line in members[group["id"]])
        lines.append("  }")
    for wire in graph["wires"]:
        style = ", style=dashed" if wire["static"] else ""
        lines.append(
            f"  {quote(wire['from'])} -> {quote(wire['to'])} [label={quote(wire['label'])}{style}];"
        )
    lines.append("}")
    return "\n".join(lines) + "\n"
