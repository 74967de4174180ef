"""``ubitrack router``: a zenoh router, the meeting point of a site's processes when the
middleware spans several machines or sites (``docs/operations.md``, "Several machines").

zenoh's own router, ``zenohd``, is not in the package registries the project installs from
(PyPI, Debian), but a zenoh session in router mode is a real router: this command opens one
with the resolved settings (mode always ``router``; listen and connect endpoints, TLS and
access control as for any process, ``net.session``) and keeps it open until SIGTERM or Ctrl-C.
One router per site; a site's router connects to the others' (``connect``). Every other
process of the site is a client of it (``mode: client``, ``connect`` the router): zenoh 1.10
does not forward between two peers of one router, so peers that cannot reach each other
directly (a worker listens on loopback only) would miss each other's data, while a router
forwards between its clients and to the other sites' routers. It routes every key, whatever
the domain.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from collections.abc import Iterable
from typing import Any

from ubitrack_agent.net import config
from ubitrack_agent.net.config import Settings


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "router",
        help="run a zenoh router: a site's meeting point, linked to the other sites' routers",
        description="Run a zenoh router (a zenoh session in router mode) with the resolved "
        "settings: listen where other machines' processes connect as clients (default "
        f"tcp/127.0.0.1:{config.DEFAULT_ROUTER_PORT}, loopback only: give --listen "
        f"tcp/0.0.0.0:{config.DEFAULT_ROUTER_PORT} or a settings file such as "
        "deploy/router.yaml), connect to the other sites' routers. The mode is always router. "
        "Routes every domain. Ends cleanly on SIGTERM or Ctrl-C.",
    )
    parser.add_argument(
        "--quiet",
        action="store_true",
        help="no status line (every 10 s: the routers, peers and clients linked)",
    )
    config.add_arguments(parser)
    parser.set_defaults(func=run)


def router_settings(args: argparse.Namespace) -> Settings:
    """The router's settings: defaults < file < environment < flags, as for every process,
    with the mode router whatever a shared file or the environment says; ``ConfigError`` for
    ``--mode`` other than router or a router listening nowhere."""
    if args.mode not in (None, "router"):
        raise config.ConfigError(f"--mode {args.mode}: a router's mode is always router")
    flags = {name: getattr(args, name, None) for name in config.SETTING_NAMES}
    settings = config.resolve("router", config_file=args.config, flags={**flags, "mode": "router"})
    if not settings.listen:
        raise config.ConfigError("a router needs a listen endpoint, where members connect")
    return settings


def status_line(transports: Iterable[Any]) -> str:
    """The router's one-line status (``net.status_line``) from its session's transports
    (``session.info.transports()``: each has ``whatami``)."""
    linked = Counter(str(transport.whatami).lower() for transport in transports)
    return (
        f"router: {linked['router']} routers, {linked['peer']} peers, "
        f"{linked['client']} clients linked"
    )


def run(args: argparse.Namespace) -> int:
    import zenoh

    from ubitrack_agent.net.lifecycle import stop_on_signals
    from ubitrack_agent.net.session import open_session
    from ubitrack_agent.net.status_line import periodic_status

    try:
        settings = router_settings(args)
    except config.ConfigError as exc:
        print(f"ubitrack router: {exc}", file=sys.stderr)
        return 2
    stop = stop_on_signals()
    try:
        session = open_session(settings)
    except zenoh.ZError as exc:
        print(f"ubitrack router: cannot open zenoh on {settings.listen}: {exc}", file=sys.stderr)
        return 2
    with session:
        linked = f", connecting to {', '.join(settings.connect)}" if settings.connect else ""
        print(
            f"ubitrack router: routing on {', '.join(settings.listen)}{linked} "
            "(every domain; members connect as clients)",
            flush=True,
        )
        with periodic_status(lambda: status_line(session.info.transports()), not args.quiet):
            stop.wait()
    return 0
