"""Graphviz DOT rendering of an SRG with a chosen solution (the design tool, section 5.2.2).

Measured edges are solid (bold when the solution reads them), edges the solution infers are
dashed and labelled with the step and pattern that derive them, like the paper's figures, and
with the host the step would run on when one is given.
"""

from __future__ import annotations

from collections.abc import Sequence

import networkx as nx

from ubitrack_agent.graph.planner import Solution, with_solution


def quote(text: str) -> str:
    """``text`` as a DOT string: backslashes and quotes escaped, a line break as DOT's ``\\n``
    (escaped once: a label with ``\\n`` in it must not show the two characters)."""
    escaped = text.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")
    return f'"{escaped}"'


def to_dot(
    srg: nx.MultiDiGraph,
    solution: Solution | None = None,
    title: str = "SRG",
    hosts: Sequence[str | None] | None = None,
) -> str:
    """DOT text of ``srg``, with the edges of ``solution`` highlighted when one is given, and
    the host each of its steps runs on (``hosts``, in step order) when given."""
    graph = srg if solution is None else with_solution(srg, solution)
    used = set(solution.records) if solution is not None else set()
    steps = {} if solution is None else {s.id: (n, s) for n, s in enumerate(solution.steps, 1)}
    lines = [f"digraph {quote(title)} {{", "  rankdir=LR;", "  node [shape=ellipse];"]
    for node in sorted(graph.nodes):
        lines.append(f"  {quote(node)};")
    for u, v, key, data in sorted(graph.edges(keys=True, data=True), key=lambda e: e[2]):
        label = data["type"] + (" static" if data["static"] else "")
        if data["measured"]:
            style = ', style=bold, color="blue"' if key in used else ""
        else:
            n, step = steps[data["derivation"]]
            label = f"{n}. {step.template.pattern} ({step.expansion}) {label}"
            if hosts is not None:
                label += f"\non {hosts[n - 1] or '(no host fits)'}"
            style = ', style=dashed, color="red", fontcolor="red"'
        lines.append(f"  {quote(u)} -> {quote(v)} [label={quote(label)}{style}];")
    lines.append("}")
    return "\n".join(lines) + "\n"
