"""``ubitrack store``: the calibration store, serving a static-edges file and saving to it."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from ubitrack_agent.core.lines import write_line
from ubitrack_agent.net import config
from ubitrack_agent.net.status_line import periodic_status

if TYPE_CHECKING:
    from ubitrack_agent.io.calibration_store import CalibrationStore


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "store",
        help="serve the static edges of a calibration file and save new calibrations to it",
        description="Announce every edge of the static-edges FILE (docs/simulators.md, "
        "'Static-edges files') as a measured static edge, one provider '<name>.<edge>' each, "
        "and save the calibrations that `ubitrack calibrate --save` sends: written atomically "
        "to FILE with their provenance, the previous value kept in the entry's history, then "
        "served. A missing FILE is a new, empty store (it says so), created on the first save; "
        "a missing folder is an error. Runs until "
        "SIGINT/SIGTERM.",
    )
    parser.add_argument("file", metavar="FILE", help="static-edges file (YAML)")
    parser.add_argument(
        "--name",
        default="store",
        help="the store's name in keys and provider ids (default: %(default)s)",
    )
    parser.add_argument(
        "--quiet", action="store_true", help="no status line (every 10 s: edges, saves)"
    )
    config.add_arguments(parser)
    parser.set_defaults(func=run)


def serving(store: CalibrationStore, file: str, key: str) -> str:
    """What the store serves, said once at its start: a missing file is a new, empty store."""
    if store.new:
        return (
            f"{file} does not exist: a new, empty store (0 edges), on {key}; the first "
            "`ubitrack calibrate ... --save` creates the file"
        )
    return f"serving {len(store.edges)} edge(s) of {file} on {key}"


def run(args: argparse.Namespace) -> int:
    from ubitrack_agent.io.calibration_store import CalibrationStore
    from ubitrack_agent.io.static_edges import StaticEdgesError
    from ubitrack_agent.net.keys import KeySpace, validate_key_chunks
    from ubitrack_agent.net.lifecycle import stop_on_signals
    from ubitrack_agent.net.session import open_session

    prog = "ubitrack store"
    try:
        settings = config.from_arguments(args, role="member")
        validate_key_chunks(args.name, single_chunk=True)
    except ValueError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    stop = stop_on_signals()
    keys = KeySpace(settings.key_prefix)
    with open_session(settings) as session:
        try:
            store = CalibrationStore(session, keys, args.file, args.name, settings.host_name)
        except (StaticEdgesError, OSError) as exc:
            print(f"{prog}: {exc}", file=sys.stderr)
            return 2
        with store:
            write_line(f"{prog}: {serving(store, args.file, keys.store(args.name))}")
            with periodic_status(
                lambda: (
                    f"store {args.name}: serving {len(store.edges)} edge(s); "
                    f"{store.counters['saved']} saved, {store.counters['refused']} refused"
                ),
                not args.quiet,
            ):
                stop.wait()
    return 0
