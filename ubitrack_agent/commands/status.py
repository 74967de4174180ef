"""``ubitrack status``: the live SRG, the queries, the workers and their counters."""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from ubitrack_agent.commands.view.flow import flow_dot
from ubitrack_agent.net import config


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "status",
        help="show the agent's live SRG, queries, workers and counters",
        description="Ask the agent for its state and every worker for its counters; print a "
        "summary (or --json). --dot FILE writes the live data flow in Graphviz DOT in the "
        "style of the paper's figure 6: providers (sources), components (boxes: pattern, "
        "instance, host), applications (sinks), wires labelled with type, rate (announced "
        "for a provider's edge, measured over --rate-window seconds for a component's output) "
        "and the latency the consumer measures; "
        "--svg FILE the same drawn by Graphviz's dot; --srg-dot FILE the live SRG with the "
        "edges the components derive (dashed).",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--dot", metavar="FILE", help="write the live data flow as DOT")
    parser.add_argument("--svg", metavar="FILE", help="draw the live data flow as SVG (Graphviz)")
    parser.add_argument("--srg-dot", metavar="FILE", help="write the live SRG as DOT")
    parser.add_argument(
        "--rate-window",
        type=float,
        default=1.0,
        help="seconds over which --dot/--svg measure the components' output rates (default 1)",
    )
    parser.add_argument("--timeout", type=float, default=2.0, help="seconds to wait for answers")
    config.add_arguments(parser)
    parser.set_defaults(func=run)


def live_dot(status: dict[str, Any]) -> str:
    """DOT of the live SRG (solid) and the edges running components derive (dashed)."""
    from ubitrack_agent.graph.dot import quote

    lines = [f"digraph {quote(status.get('key_prefix', 'SRG'))} {{", "  rankdir=LR;"]
    for edge in status.get("srg", []):
        label = edge["type"] + (" static" if edge["static"] else "")
        lines.append(f"  {quote(edge['from'])} -> {quote(edge['to'])} [label={quote(label)}];")
    for instance, component in status.get("components", {}).items():
        colour = "red" if component.get("alive") else "grey"
        for source, target, edge_type in component.get("derives", []):
            label = f"{component['service']} {edge_type}\n{instance}"
            lines.append(
                f"  {quote(source)} -> {quote(target)} [label={quote(label)}, style=dashed, "
                f"color={colour}, fontcolor={colour}];"
            )
    lines.append("}")
    return "\n".join(lines) + "\n"


def worker_statuses(session: Any, keys: Any, timeout: float) -> dict[str, dict[str, Any]]:
    """Every worker's status, by instance: its ``counters`` and its inputs' ``latency_ms``
    (empty if malformed); a reply that is not a worker's status (malformed JSON, no instance
    or counters) is left out."""
    from ubitrack_agent.net.transport import fetch_latest

    workers = {}
    for payload in fetch_latest(session, keys.all_statuses(), timeout=timeout):
        try:
            answer = json.loads(payload)
        except (ValueError, RecursionError):  # not JSON, or nested too deep to parse
            continue
        if not isinstance(answer, dict):
            continue
        instance, counters = answer.get("instance"), answer.get("counters")
        if isinstance(instance, str) and isinstance(counters, dict):
            latency = answer.get("latency_ms")
            latency = latency if isinstance(latency, dict) else {}
            workers[instance] = {
                "counters": counters,
                "latency_ms": {
                    key: value
                    for key, value in latency.items()
                    if type(value) in (int, float) and math.isfinite(value)
                },
            }
    return workers


NO_GRAPHVIZ = "Graphviz's dot is not installed (Debian: apt install graphviz)"


def render_svg(dot: str) -> tuple[str | None, str | None]:
    """``dot`` drawn as SVG text by Graphviz's ``dot``, or None and why not."""
    if shutil.which("dot") is None:
        return None, NO_GRAPHVIZ
    try:
        drawn = subprocess.run(
            ["dot", "-Tsvg"], input=dot, text=True, capture_output=True, check=False, timeout=10
        )
    except subprocess.TimeoutExpired:
        return None, "Graphviz's dot took longer than 10 s"
    if drawn.returncode != 0:
        return None, drawn.stderr.strip() or f"dot exited with status {drawn.returncode}"
    return drawn.stdout, None


def draw_svg(dot: str, path: str) -> str | None:
    """Draw ``dot`` into the SVG file ``path`` with Graphviz's ``dot``; why not, if it fails."""
    svg, failed = render_svg(dot)
    if svg is None:
        return f"{failed}; use --dot" if failed == NO_GRAPHVIZ else failed
    Path(path).write_text(svg, encoding="utf-8")
    return None


def run(args: argparse.Namespace) -> int:
    from ubitrack_agent.net.keys import KeySpace
    from ubitrack_agent.net.session import open_session
    from ubitrack_agent.net.transport import fetch_latest

    try:
        settings = config.from_arguments(args, role="member")
    except config.ConfigError as exc:
        print(f"ubitrack status: {exc}", file=sys.stderr)
        return 2
    keys = KeySpace(settings.key_prefix)
    with open_session(settings) as session:
        status = None
        deadline = time.monotonic() + args.timeout
        while status is None and time.monotonic() < deadline:
            replies = fetch_latest(session, keys.agent_status(), timeout=0.2)
            if replies:
                status = json.loads(replies[0])
            else:
                time.sleep(0.05)  # links come up in the background after opening
        if status is None:
            standbys = fetch_latest(session, keys.all_agent_statuses(), timeout=0.2)
            waiting = f" ({len(standbys)} agent(s) standing by or settling)" if standbys else ""
            print(
                f"ubitrack status: no active agent answers on {keys.agent_status()}{waiting}",
                file=sys.stderr,
            )
            return 1
        workers = worker_statuses(session, keys, args.timeout)
        rates: dict[str, float] = {}
        if args.dot or args.svg:  # output rates: published samples over the window
            began = time.monotonic()
            time.sleep(args.rate_window)
            later = worker_statuses(session, keys, args.timeout)
            window = time.monotonic() - began
            for instance, worker in later.items():
                before = workers.get(instance, {}).get("counters", {}).get("published", 0)
                rates[instance] = (worker["counters"].get("published", 0) - before) / window
            workers.update(later)
    for instance, component in status["components"].items():
        worker = workers.get(instance, {})
        component["counters"] = worker.get("counters")
        component["latency_ms"] = worker.get("latency_ms", {})
    if args.srg_dot:
        Path(args.srg_dot).write_text(live_dot(status), encoding="utf-8")
    if args.dot:
        Path(args.dot).write_text(flow_dot(status, rates), encoding="utf-8")
    if args.svg and (failed := draw_svg(flow_dot(status, rates), args.svg)):
        print(f"ubitrack status: --svg: {failed}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(status, indent=2))
        return 0
    print(
        f"agent {status['agent']['id']} (active) on {status['key_prefix']}: "
        f"{len(status['srg'])} SRG edges from {len(status['providers'])} providers"
    )
    for standby in status["agent"]["standby"]:
        print(f"  standby agent {standby}: takes over if this one ends")
    for provider, reason in status["rejected_providers"].items():
        print(f"  rejected provider {provider}: {reason}")
    for edge_id in status.get("stale_edges", []):
        print(f"  stale edge {edge_id}: its data stopped, planned without it")
    for name, info in status.get("host_info", {}).items():
        labels = f", labels {', '.join(info['labels'])}" if info["labels"] else ""
        clock = info.get("clock")
        offset = (
            f", clock {clock['offset_ns'] / 1e6:+.3f} ms (+-{clock['uncertainty_ns'] / 1e6:.3f})"
            if clock
            else ", clock not measured yet"
        )
        print(
            f"host {name}: capacity {info['capacity']}, CPU load {info['cpu_load']:.2f}"
            f"{labels}{offset}"
        )
    for relation, apps in status["queries"].items():
        hosts = status.get("application_hosts", {}).get(relation, [])
        where = f" on {', '.join(hosts)}" if hosts else ""
        print(f"query {relation} from {', '.join(apps)}{where}")
    for name, reason in status["unsolved"].items():
        print(f"  unsolved {name}: {reason}")
    for instance, component in status["components"].items():
        state = "alive" if component["alive"] else "starting"
        where = f" on {component['host']}" if component.get("host") else ""
        where += f" in {component['container']}" if component.get("container") else ""
        print(
            f"worker {instance} ({component['service']}, {state}{where}): {component['counters']}"
        )
    for name, relation in status.get("relations", {}).items():
        for producer in relation.get("spares", []):
            print(f"  spare {producer} of {name}: takes the key if a sensor of its flow is lost")
    for instance in status.get("standby_components", []):
        print(f"  standby {instance}: the old flow of a relation that lost a sensor, kept")
    for instance, reason in status.get("unplaced", {}).items():
        print(f"  unplaced {instance}: {reason}")
    for instance, reason in status.get("clock_problems", {}).items():
        print(f"  clocks of {instance}: {reason}")
    print(f"counters: {status['counters']}")
    for counter, reason in status.get("problems", {}).items():
        print(f"  last {counter}: {reason}")
    return 0
