"""The ``ubitrack`` command line: one subcommand per module in :mod:`ubitrack_agent.commands`.

Each command module defines ``register(subparsers)``, which adds its parser and sets
``func`` to a callable taking the parsed arguments and returning the exit status. Modules
import their heavy dependencies (zenoh, OpenCV) inside that callable, so ``--help`` is quick.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from ubitrack_agent import __version__
from ubitrack_agent.net import logs

COMMAND_MODULES: tuple[str, ...] = (
    "agent",
    "host",
    "router",
    "plan",
    "subscribe",
    "calibrate",
    "store",
    "status",
    "view",
    "sim",
    "dtrack",
    "natnet",
    "ros2",
    "camera",
    "intrinsics",
    "config",
    "certs",
    "demo",
    "record",
    "replay",
)
"""Modules of :mod:`ubitrack_agent.commands`, in the order ``--help`` lists them."""


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The parser of every subcommand, or of ``only`` that one (its module alone is imported:
    a restarted agent is up sooner without the others' imports)."""
    parser = argparse.ArgumentParser(
        prog="ubitrack",
        description="Spatial relationship pattern middleware for tracking and calibration.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    logs.add_log_level_argument(parser)
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMAND_MODULES if only is None else (only,):
        importlib.import_module(f"{__package__}.commands.{name}").register(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    arguments = sys.argv[1:] if argv is None else argv
    command = next((a for a in arguments if a in COMMAND_MODULES), None)
    args = build_parser(command).parse_args(arguments)
    logs.configure(args.log_level)
    try:
        code = int(args.func(args) or 0)
        sys.stdout.flush()  # here, where a closed pipe is caught, not at the interpreter's exit
        return code
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # the reader went away (``ubitrack plan ... | head``)
        # What Python's documentation advises ("Note on SIGPIPE"): no further write to the
        # closed pipe, so the interpreter's flush at exit raises nothing either.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141  # a shell's code for a command ended by SIGPIPE


if __name__ == "__main__":
    sys.exit(main())
