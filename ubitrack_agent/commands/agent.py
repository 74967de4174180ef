"""``ubitrack agent``: run the live agent (the zenoh hub of the embedded default)."""

from __future__ import annotations

import argparse
import signal
import sys

from ubitrack_agent.net import config


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "agent",
        help="run the agent: watch providers and queries, plan, start and rewire workers",
        description="Watch providers and application queries on zenoh, plan every queried "
        "relation with the pattern templates, and start, stop and rewire pattern workers so "
        "that each relation flows on its stable key. Ends cleanly on SIGTERM or Ctrl-C, "
        "stopping the workers it started.",
    )
    parser.add_argument(
        "--templates", metavar="DIR", help="template directory (default: the shipped templates/)"
    )
    parser.add_argument(
        "--pool-size",
        type=int,
        default=8,
        help="idle pre-started workers kept ready for fast reconfiguration; each holds about "
        "100 MB (default: %(default)s)",
    )
    config.add_arguments(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import zenoh

    from ubitrack_agent.agent.runtime import Agent
    from ubitrack_agent.graph.templates import TemplateError, load_templates

    try:
        settings = config.from_arguments(args, role="hub")
        templates = load_templates(args.templates)
    except (config.ConfigError, TemplateError) as exc:
        print(f"ubitrack agent: {exc}", file=sys.stderr)
        return 2
    if args.pool_size < 0:
        print("ubitrack agent: --pool-size must be >= 0", file=sys.stderr)
        return 2
    try:
        agent = Agent(settings, templates, config.member_flags(settings), args.pool_size)
    except zenoh.ZError as exc:
        print(f"ubitrack agent: cannot open zenoh on {settings.listen}: {exc}", file=sys.stderr)
        return 2
    signal.signal(signal.SIGTERM, lambda *_: agent.stop())
    signal.signal(signal.SIGINT, lambda *_: agent.stop())
    print(f"ubitrack agent: serving {agent.keys.root} on {', '.join(settings.listen)}", flush=True)
    agent.run()
    return 0
