"""Graphviz DOT rendering of an SRG with a chosen solution (the design tool, section 5.2.2).

Measured edges are solid (bold when the solution reads them), edges the solution infers are
dashed and labelled with the pattern that derives them, like the paper's figures.
"""

from __future__ import annotations

import networkx as nx

from .planner import Solution


def _quote(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def to_dot(srg: nx.MultiDiGraph, solution: Solution | None = None, title: str = "SRG") -> str:
    """DOT text of ``srg``, with the edges of ``solution`` highlighted when one is given."""
    used = set(solution.records) if solution is not None else set()
    lines = [f"digraph {_quote(title)} {{", "  rankdir=LR;", "  node [shape=ellipse];"]
    for node in sorted(srg.nodes):
        lines.append(f"  {_quote(node)};")
    for u, v, key, data in sorted(srg.edges(keys=True, data=True), key=lambda e: e[2]):
        label = data["type"] + (" static" if data["static"] else "")
        style = ', style=bold, color="blue"' if key in used else ""
        lines.append(f"  {_quote(u)} -> {_quote(v)} [label={_quote(label)}{style}];")
    if solution is not None:
        for n, step in enumerate(solution.steps, start=1):
            for _, src, dst, typ, edge_id in step.outputs:
                if edge_id is None:
                    continue
                label = f"{n}. {step.template.pattern} ({step.expansion}) {typ}"
                if solution.records[edge_id].static:
                    label += " static"
                lines.append(
                    f"  {_quote(src)} -> {_quote(dst)} "
                    f'[label={_quote(label)}, style=dashed, color="red", fontcolor="red"];'
                )
    lines.append("}")
    return "\n".join(lines) + "\n"
