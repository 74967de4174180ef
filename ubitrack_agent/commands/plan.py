"""``ubitrack plan``: the offline tracking setup design tool (paper section 5.2.2).

Reads setup files, static-edges files and simulator scenarios, merged into one SRG
(:mod:`ubitrack_agent.commands.plan_inputs`), plans the queried relationship and prints the
solutions; works with no network at all.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from ubitrack_agent.graph.srg import EDGE_TYPES

if TYPE_CHECKING:
    import networkx as nx

    from ubitrack_agent.graph.planner import Query, Solution


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``plan`` subcommand."""
    parser = subparsers.add_parser(
        "plan",
        help="plan how to derive a spatial relationship from setup files (offline)",
        description=(
            "Find the derivations of FROM->TO in the SRG of the FILEs with the pattern "
            "templates, best first by expected error, latency and number of sensors "
            "(docs/planner.md). Each FILE is a setup file, a static-edges file (what "
            "'ubitrack store' and 'ubitrack sim database --edges' serve; its entries are "
            "static edges of its provider, replacing the setups' static edges of the same "
            "relation) or a simulator scenario, told apart by their top-level keys. "
            "Exit status: 0 if there is a solution, 2 if there is none, 1 if an input or "
            "template file is invalid."
        ),
    )
    parser.add_argument(
        "files",
        nargs="+",
        metavar="FILE",
        help="setup file (edges:), static-edges file (provider:, edges:) or simulator "
        "scenario (frames:, ...); their edges are merged; give the FILEs one after another",
    )
    parser.add_argument(
        "--from", dest="source", required=True, metavar="FRAME", help="source frame"
    )
    parser.add_argument("--to", dest="target", required=True, metavar="FRAME", help="target frame")
    parser.add_argument(
        "--type", required=True, choices=sorted(EDGE_TYPES), help="edge type of the relationship"
    )
    parser.add_argument(
        "--static",
        action="store_true",
        help="the relationship is static (rigid): only static results, calibration allowed",
    )
    parser.add_argument("--all", action="store_true", help="list every distinct solution")
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    parser.add_argument(
        "--dot",
        metavar="FILE",
        help="write the SRG with the best solution as Graphviz DOT to FILE "
        "(and FILE.svg if the 'dot' program is installed)",
    )
    parser.add_argument(
        "--without",
        action="append",
        default=[],
        metavar="PROVIDER",
        help="plan as if this provider's edges were gone (a sensor failing), repeatable",
    )
    parser.add_argument(
        "--host",
        dest="hosts",
        action="append",
        default=[],
        type=host_option,
        metavar="NAME[:LABEL,...]",
        help="a host manager to place the components on, with its labels, repeatable: each "
        "step is shown with the host it would run on (the edges' 'host' fields say where "
        "their providers run; docs/architecture.md, 'Placement')",
    )
    parser.add_argument(
        "--app-host",
        metavar="NAME",
        help="the host the application asking for the relationship runs on (with --host)",
    )
    parser.add_argument(
        "--templates",
        metavar="DIR",
        help="directory of template files (default: the templates shipped with the package)",
    )
    parser.set_defaults(func=run)


def host_option(text: str) -> tuple[str, frozenset[str]]:
    """``--host NAME[:LABEL,...]``."""
    from ubitrack_agent.net.keys import validate_key_chunks

    name, _, labels = text.partition(":")
    names = [name, *(labels.split(",") if labels else [])]
    try:
        checked = [validate_key_chunks(part, single_chunk=True) for part in names]
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"{text!r}: {exc}") from None
    return checked[0], frozenset(checked[1:])


def step_hosts(
    srg: nx.MultiDiGraph,
    solution: Solution,
    query: Query,
    hosts: list[tuple[str, frozenset[str]]],
    app_host: str | None,
) -> list[str | None]:
    """The host each step of ``solution`` would run on (:mod:`ubitrack_agent.agent.placement`),
    None where none fits."""
    from ubitrack_agent.agent.materialise import component_specs
    from ubitrack_agent.agent.placement import place
    from ubitrack_agent.graph.dataflow import from_solution, relation_name
    from ubitrack_agent.net.host_protocol import HostInfo
    from ubitrack_agent.net.keys import RelationId

    flow = from_solution(solution, query)
    relation = RelationId(query.source, query.target, query.type, query.static)
    # The flow's components are the solution's steps, in order.
    steps = zip(flow.components, solution.steps, strict=True)
    labels = {cid: step.template.host_labels for cid, step in steps}
    specs = component_specs(flow, srg, _EdgeIds(), {relation_name(query): relation})
    data_hosts = {edge: host for *_, edge, host in srg.edges(keys=True, data="host") if host}
    readers = {"relation": {app_host}} if app_host else {}
    infos = {name: HostInfo(name, tags) for name, tags in hosts}
    placement = place(specs, infos, data_hosts, readers, {}, labels)
    return [placement.hosts.get(component) for component in flow.components]


class _EdgeIds:
    """Keys for placing a plan offline: a setup's edge ids need not be key names (``C->IP:3x4``),
    and placement only tells streams apart."""

    def data(self, edge_id: str) -> str:
        return edge_id

    def relation(self, relation: object) -> str:
        return "relation"


def _render(dot_path: Path) -> None:
    """Render ``dot_path`` to SVG next to it when Graphviz is installed."""
    dot = shutil.which("dot")
    if dot is None:
        print(f"wrote {dot_path} (install graphviz to render it: dot -Tsvg)", file=sys.stderr)
        return
    svg = dot_path.with_name(dot_path.name + ".svg")
    subprocess.run([dot, "-Tsvg", str(dot_path), "-o", str(svg)], check=True)
    print(f"wrote {dot_path} and {svg}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    """Plan the query of ``args``; print the solutions; 0 if found, 2 if none, 1 on bad input."""
    from ubitrack_agent.commands.plan_inputs import load_plan_srg
    from ubitrack_agent.graph.dot import to_dot
    from ubitrack_agent.graph.planner import NoSolutionError, PlanningError, Query, plan
    from ubitrack_agent.graph.srg import SetupError, remove_provider
    from ubitrack_agent.graph.templates import TemplateError, load_templates

    try:
        srg, notes = load_plan_srg(args.files)
        for note in notes:
            print(f"ubitrack plan: {note}", file=sys.stderr)
        providers = {data["provider"] for *_, data in srg.edges(data=True)}
        for provider in args.without:
            if provider not in providers:
                raise SetupError(f"--without {provider}: no such provider; {sorted(providers)}")
            srg = remove_provider(srg, provider)
        templates = load_templates(args.templates)
        query = Query(args.source, args.target, args.type, args.static)
        found = plan(srg, templates, query)
    except NoSolutionError as exc:
        print(f"ubitrack plan: no solution: {exc}", file=sys.stderr)
        return 2
    except (SetupError, TemplateError, PlanningError) as exc:
        print(f"ubitrack plan: {exc}", file=sys.stderr)
        return 1
    shown = found if args.all else found[:1]
    if args.app_host and not args.hosts:
        print("ubitrack plan: --app-host needs --host", file=sys.stderr)
        return 1
    placed = [
        step_hosts(srg, solution, query, args.hosts, args.app_host) if args.hosts else None
        for solution in shown
    ]
    if args.json:
        document = {
            "query": {
                "from": query.source,
                "to": query.target,
                "type": query.type,
                "static": query.static,
            },
            "solutions": [
                {**s.as_json(), **({"hosts": hosts} if hosts is not None else {})}
                for s, hosts in zip(shown, placed, strict=True)
            ],
        }
        print(json.dumps(document))
    else:
        kind = "static " if query.static else ""
        hidden = len(found) - len(shown)
        more = f", the best shown (--all for the other {hidden})" if hidden else ""
        print(f"{kind}{query.type} {query.source}->{query.target}: {len(found)} solution(s){more}")
        for n, (solution, hosts) in enumerate(zip(shown, placed, strict=True), start=1):
            state = "static" if solution.static else "dynamic"
            print(f"\nsolution {n}: cost {solution.cost:.3f}, {state}")
            for k, step in enumerate(solution.as_json()["steps"], start=1):
                ins = ", ".join(f"{a}->{b}:{t}" for a, b, t in step["inputs"])
                outs = ", ".join(f"{a}->{b}:{t}" for a, b, t in step["outputs"])
                where = "" if hosts is None else f"  on {hosts[k - 1] or '(no host fits)'}"
                print(f"  {k}. {step['pattern']} ({step['expansion']}): {ins}  =>  {outs}{where}")
            measured = (
                f"{e.source}->{e.target}:{e.type} ({e.provider})" for e in solution.measured()
            )
            print(f"  measured: {', '.join(measured)}")
    if args.dot:
        path = Path(args.dot)
        title = f"{query.source}->{query.target}"
        path.write_text(to_dot(srg, found[0], title, placed[0]), encoding="utf-8")
        _render(path)
    return 0
