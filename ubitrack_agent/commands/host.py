"""``ubitrack host``: run this machine's host manager (``ubitrack_agent.services.host``) on its own,
for an agent started with ``--no-host`` or on another machine."""

from __future__ import annotations

import argparse
import sys

from ubitrack_agent.net import config
from ubitrack_agent.services import host


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "host",
        help="run this machine's host manager: starts and stops workers for the agent",
        description="Start, stop and supervise this machine's pattern workers for the agent, "
        "over zenoh, keeping a warm pool of idle workers. One per machine: one started while "
        "another of its name serves, or started with it and second by start time, exits with "
        "status 3. Adopts the containers a host manager of its name that died left running. "
        "Ends on SIGTERM or Ctrl-C, ending every worker it started.",
    )
    host.add_arguments(parser)
    config.add_arguments(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    try:
        settings = config.from_arguments(args, role="member")
    except config.ConfigError as exc:
        print(f"ubitrack host: {exc}", file=sys.stderr)
        return 2
    return host.serve(
        settings,
        args.name,
        args.pool_size,
        quiet=args.quiet,
        labels=args.labels,
        capacity=args.capacity,
        cores=args.cores,
        isolate=args.isolate,
        workers_as_peers=args.workers_as_peers,
    )
