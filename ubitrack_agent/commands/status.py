"""``ubitrack status``: the live SRG, the queries, the workers and their counters."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from ubitrack_agent.net import config


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "status",
        help="show the agent's live SRG, queries, workers and counters",
        description="Ask the agent for its state and every worker for its counters; print a "
        "summary (or --json). --dot FILE writes the live SRG with the running data flow "
        "(measured edges solid, derived edges dashed) in Graphviz DOT.",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--dot", metavar="FILE", help="write the live SRG and data flow as DOT")
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
        workers = {}
        for payload in fetch_latest(session, keys.all_statuses(), timeout=args.timeout):
            answer = json.loads(payload)
            workers[answer["instance"]] = answer["counters"]
    for instance, component in status["components"].items():
        component["counters"] = workers.get(instance)
    if args.dot:
        Path(args.dot).write_text(live_dot(status), encoding="utf-8")
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
    for relation, apps in status["queries"].items():
        print(f"query {relation} from {', '.join(apps)}")
    for name, reason in status["unsolved"].items():
        print(f"  unsolved {name}: {reason}")
    for instance, component in status["components"].items():
        state = "alive" if component["alive"] else "starting"
        print(f"worker {instance} ({component['service']}, {state}): {component['counters']}")
    print(f"counters: {status['counters']}")
    for counter, reason in status.get("problems", {}).items():
        print(f"  last {counter}: {reason}")
    return 0
