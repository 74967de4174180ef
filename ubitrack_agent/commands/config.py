"""``ubitrack config``: show the zenoh settings a process would use, and where they came from."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict

from ubitrack_agent.net import config


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "config",
        help="print the resolved zenoh settings as JSON",
        description="Resolve defaults < --config file < UBITRACK_* environment < flags and "
        "print the result, with the zenoh options it produces.",
    )
    parser.add_argument(
        "--role",
        choices=("hub", "member", "router"),
        default="member",
        help="hub: the agent, listening on the well-known port; router: ubitrack router (its "
        "mode is always router); member: any other process (default: %(default)s)",
    )
    config.add_arguments(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ubitrack_agent.commands.router import router_settings

    try:
        if args.role == "router":
            settings = router_settings(args)  # as ubitrack router resolves them
        else:
            settings = config.from_arguments(args, role=args.role)
    except config.ConfigError as exc:
        print(f"ubitrack config: {exc}", file=sys.stderr)
        return 2
    print(
        json.dumps(
            {
                "role": args.role,
                "key_prefix": settings.key_prefix,
                "settings": asdict(settings),
                "zenoh": settings.zenoh_options(),
            },
            indent=2,
        )
    )
    return 0
