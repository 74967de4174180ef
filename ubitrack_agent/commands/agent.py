"""``ubitrack agent``: run the live agent (the zenoh hub of the embedded default), with a host
manager for its own machine as a child process unless ``--no-host``."""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys

from services.host import DEFAULT_POOL_SIZE
from ubitrack_agent.net import config

HOST_EXIT_S = 10.0
"""How long the host manager may take to end its workers (it kills them after its own grace
period) before it is killed itself."""


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "agent",
        help="run the agent: watch providers and queries, plan, start and rewire workers",
        description="Watch providers and application queries on zenoh, plan every queried "
        "relation with the pattern templates, and have host managers start, stop and rewire "
        "pattern workers so that each relation flows on its stable key. Starts a host manager "
        "for this machine (python -m services.host) unless --no-host. Ends cleanly on SIGTERM "
        "or Ctrl-C, stopping every worker it runs.",
    )
    parser.add_argument(
        "--templates", metavar="DIR", help="template directory (default: the shipped templates/)"
    )
    parser.add_argument(
        "--pool-size",
        type=int,
        default=DEFAULT_POOL_SIZE,
        help="idle pre-started workers the host manager keeps ready for fast reconfiguration; "
        "each holds about 100 MB (default: %(default)s)",
    )
    parser.add_argument(
        "--no-host",
        action="store_true",
        help="start no host manager: workers run where `ubitrack host` runs",
    )
    config.add_arguments(parser)
    parser.set_defaults(func=run)


def start_host(settings: config.Settings, pool_size: int, log_level: str) -> subprocess.Popen:
    """The host manager for this machine, joined to the agent's network. Its standard input is a
    pipe from this process, so it ends when the agent dies (leaving assigned workers running
    for a restarted agent to adopt; its idle pool workers end with it)."""
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "services.host",
            "--exit-when-stdin-closes",
            "--pool-size",
            str(pool_size),
            "--log-level",
            log_level,
            *config.member_flags(settings),
        ],
        stdin=subprocess.PIPE,
    )


def stop_host(host: subprocess.Popen) -> None:
    """End the host manager, which ends every worker it started."""
    host.terminate()
    try:
        host.wait(timeout=HOST_EXIT_S)
    except subprocess.TimeoutExpired:
        host.kill()
        host.wait()


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
        agent = Agent(settings, templates)
    except zenoh.ZError as exc:
        print(f"ubitrack agent: cannot open zenoh on {settings.listen}: {exc}", file=sys.stderr)
        return 2
    signal.signal(signal.SIGTERM, lambda *_: agent.stop())
    signal.signal(signal.SIGINT, lambda *_: agent.stop())
    host = None if args.no_host else start_host(settings, args.pool_size, args.log_level)
    print(f"ubitrack agent: serving {agent.keys.root} on {', '.join(settings.listen)}", flush=True)
    try:
        agent.run()
    finally:
        if host is not None:
            stop_host(host)
    return 0
