"""``ubitrack record FILE.mcap``: record what the providers announce and publish.

Writes an MCAP file (``docs/recording.md``): every provider's announcement (its SRG fragment,
so the SRG can be rebuilt) and withdrawal, every measurement of their edges as it travelled
(timestamps, values and covariances bit-exact), and one ``foxglove.FrameTransform`` channel per
6D or 3D edge for viewers such as Foxglove. Providers already running are recorded from the
start (static edges with their latest value). It runs until SIGINT (Ctrl-C) or SIGTERM, or
``--duration`` seconds, and then finishes the file (summary and index written) and exits 0.
A line is printed for each provider announced or withdrawn, and a status line every 10 s.
Needs the ``mcap`` extra: ``pip install "ubitrack-agent[mcap]"`` (exit 2 without it, or for a
bad option or an existing FILE without ``--overwrite``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ubitrack_agent.core.lines import write_line
from ubitrack_agent.net import config

EXTRA_HINT = 'pip install "ubitrack-agent[mcap]"'


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "record",
        help="record the providers' announcements and measurements to an MCAP file",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("file", metavar="FILE.mcap", help="the recording to write")
    parser.add_argument(
        "--provider",
        action="append",
        default=[],
        metavar="ID",
        help="record only this provider (repeatable; default: every provider)",
    )
    parser.add_argument(
        "--duration", type=float, help="stop after this many seconds (default: until stopped)"
    )
    parser.add_argument("--overwrite", action="store_true", help="replace an existing FILE")
    parser.add_argument("--json", action="store_true", help="print JSON lines instead of text")
    parser.add_argument("--quiet", action="store_true", help="no status line (every 10 s)")
    config.add_arguments(parser)
    parser.set_defaults(func=run)


def missing_extra(prog: str, exc: ImportError) -> int:
    """Say which extra to install; the exit status 2."""
    print(f"{prog}: needs the mcap extra ({exc.name} is missing): {EXTRA_HINT}", file=sys.stderr)
    return 2


def member_settings(args: argparse.Namespace, prog: str) -> config.Settings | None:
    """The zenoh settings of a member process; ``None`` after printing why they are invalid."""
    try:
        return config.from_arguments(args, role="member")
    except config.ConfigError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return None


def printer(as_json: bool):
    """``say(event, text)``: one JSON line or the text, flushed."""

    def say(event: dict, text: str) -> None:
        write_line(json.dumps(event) if as_json else text)

    return say


def run(args: argparse.Namespace) -> int:
    prog = "ubitrack record"
    try:
        from ubitrack_agent.io.recording.recorder import Recorder
        from ubitrack_agent.io.recording.writer import RecordingWriter
    except ImportError as exc:
        return missing_extra(prog, exc)
    from ubitrack_agent.net.keys import KeySpace
    from ubitrack_agent.net.lifecycle import stop_on_signals
    from ubitrack_agent.net.session import open_session
    from ubitrack_agent.net.status_line import Rate, periodic_status

    if (settings := member_settings(args, prog)) is None:
        return 2
    if args.duration is not None and not args.duration > 0:
        print(f"{prog}: --duration must be > 0", file=sys.stderr)
        return 2
    path = Path(args.file)
    if path.exists() and not args.overwrite:
        print(f"{prog}: {path} exists (give --overwrite to replace it)", file=sys.stderr)
        return 2
    say = printer(args.json)
    stop = stop_on_signals()
    try:
        stream = path.open("wb")
    except OSError as exc:
        print(f"{prog}: cannot write {path}: {exc}", file=sys.stderr)
        return 2

    def changed(provider: str, announced) -> None:
        if announced is None:
            say({"event": "withdrawn", "provider": provider}, f"provider {provider} withdrawn")
        else:
            edges = len(announced.edges)
            say(
                {"event": "announced", "provider": provider, "edges": edges},
                f"recording provider {provider}: {edges} edges",
            )

    with stream, open_session(settings) as session:
        writer = RecordingWriter(stream)
        recorder = Recorder(
            session, KeySpace(settings.key_prefix), writer, set(args.provider), changed
        )
        rate = Rate(lambda: writer.counters["measurements"])

        def line() -> str:
            return (
                f"record: {rate.per_second():.1f} measurements/s, "
                f"{writer.counters['measurements']} in all, {recorder.backlog} waiting to be "
                f"written, providers {recorder.providers}"
            )

        try:
            with periodic_status(line, not args.quiet and not args.json):
                stop.wait(args.duration)
        finally:
            recorder.close()
            writer.finish()
        counts = {**writer.counters, **recorder.counters}
    size = path.stat().st_size
    say(
        {"event": "finished", "file": str(path), "bytes": size, **counts},
        f"wrote {path} ({size} bytes, finished): {counts.get('measurements', 0)} measurements, "
        f"{counts.get('announcements', 0)} announcements, {counts.get('withdrawals', 0)} "
        f"withdrawals; rejected {counts.get('rejected_fragments', 0)} fragments and "
        f"{counts.get('rejected_samples', 0)} samples"
        + (
            f"; dropped {counts['dropped_backlog']} samples with the backlog full"
            if counts.get("dropped_backlog")
            else ""
        ),
    )
    return 0
