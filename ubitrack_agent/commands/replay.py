"""``ubitrack replay FILE.mcap``: announce and publish a recording's providers again.

Reads a file of ``ubitrack record`` (``docs/recording.md``) and checks all of it first: a
malformed file (truncated, of another profile, wrong schemas, hostile contents) is refused with
the reason and exit status 1 before anything is announced. Then it announces each recorded
provider as the recording did (on this machine's host name) and publishes every recorded
measurement, so the agent plans and calibrates on it as on the live system. Replay into a
domain where the recorded providers are not live: it warns if one is (two providers of one id).

Pacing keeps the recorded spacing: an event is handed on as long after the first as it was
received after it while recording, divided by ``--speed``. Timestamps keep their recorded
spacing and are, by default, shifted to now: each by one constant, the time from the
recording's first event to the start of the replay pass (printed), so at speed 1 every sample
is as old when published as it was when recorded. ``--timestamps recorded`` publishes them as
recorded instead (not with ``--loop``). At another speed the shifted timestamps drift from the
clock: the agent's workers refuse samples more than 10 s ahead of their clock. ``--loop`` plays
the file again and again, each pass shifted to its own start, until SIGINT/SIGTERM.

Exit status: 0 played (or stopped by a signal), 1 a malformed recording, 2 bad options or the
``mcap`` extra missing (``pip install "ubitrack-agent[mcap]"``).
"""

from __future__ import annotations

import argparse
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from ubitrack_agent.commands.record import member_settings, missing_extra, printer
from ubitrack_agent.net import config

TIMESTAMPS = ("shifted", "recorded")


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "replay",
        help="announce and publish a recording's providers again (ubitrack record's files)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("file", metavar="FILE.mcap", help="a recording of ubitrack record")
    parser.add_argument(
        "--speed", type=float, default=1.0, help="pace: 2 plays twice as fast (default: 1)"
    )
    parser.add_argument("--loop", action="store_true", help="play again from the start at the end")
    parser.add_argument(
        "--timestamps",
        choices=TIMESTAMPS,
        default="shifted",
        help="shifted: moved to now, recorded spacing kept (default); recorded: as recorded",
    )
    parser.add_argument("--json", action="store_true", help="print JSON lines instead of text")
    config.add_arguments(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    prog = "ubitrack replay"
    try:
        from ubitrack_agent.io.recording.layout import RecordingError
        from ubitrack_agent.io.recording.reader import check_recording, read_recording
        from ubitrack_agent.io.recording.replayer import Replayer, live_providers
    except ImportError as exc:
        return missing_extra(prog, exc)
    from ubitrack_agent.net.keys import KeySpace
    from ubitrack_agent.net.lifecycle import stop_on_signals
    from ubitrack_agent.net.session import open_session

    if (settings := member_settings(args, prog)) is None:
        return 2
    if not 0 < args.speed <= 1000:
        print(f"{prog}: --speed must be in (0, 1000], got {args.speed}", file=sys.stderr)
        return 2
    shift = args.timestamps == "shifted"
    if args.loop and not shift:
        print(
            f"{prog}: --loop needs --timestamps shifted (a pass would go back in time)",
            file=sys.stderr,
        )
        return 2
    path = Path(args.file)
    say = printer(args.json)

    def events():
        with path.open("rb") as stream:
            yield from read_recording(stream)

    try:
        with path.open("rb") as stream:
            contents = check_recording(stream)
    except OSError as exc:
        print(f"{prog}: cannot read {path}: {exc}", file=sys.stderr)
        return 1
    except RecordingError as exc:
        print(f"{prog}: {path}: {exc}", file=sys.stderr)
        return 1
    timestamps = (
        "timestamps shifted to now (recorded spacing kept)" if shift else "timestamps as recorded"
    )
    say(
        {
            "event": "loaded",
            "file": str(path),
            "providers": list(contents.providers),
            "samples": contents.samples,
            "seconds": round(contents.seconds, 3),
            "speed": args.speed,
            "timestamps": args.timestamps,
            "loop": args.loop,
        },
        f"replaying {path}: {contents.samples} samples of providers {list(contents.providers)} "
        f"over {contents.seconds:.1f} s, at speed {args.speed:g}, {timestamps}"
        + (", looping" if args.loop else ""),
    )
    stop = stop_on_signals()
    keys = KeySpace(settings.key_prefix)
    with open_session(settings) as session:
        if clash := sorted(live_providers(session, keys) & set(contents.providers)):
            print(
                f"{prog}: warning: providers {clash} are live on {keys.root} already: the agent "
                "will see two providers of one id (replay into a domain without them)",
                file=sys.stderr,
            )
        with Replayer(session, keys, settings.host_name, args.speed, shift, stop) as replayer:
            passes = _play(replayer, events, args.loop, stop, say, f"{prog}: {path}")
    if passes is None:
        return 1
    say({"event": "finished", "passes": passes}, f"replay finished after {passes} passes")
    return 0


def _play(
    replayer: Any,
    events: Callable[[], Iterator[Any]],
    loop: bool,
    stop: threading.Event,
    say: Callable[[dict, str], None],
    where: str,
) -> int | None:
    """Play passes of ``events()`` (one, or until ``stop`` with ``loop``), saying each; the
    number played, or ``None`` after printing why the file could not be read again."""
    from ubitrack_agent.io.recording.layout import RecordingError

    passes = 0
    while not stop.is_set():
        try:
            finished = replayer.play(events())
        except (OSError, RecordingError) as exc:  # the file changed since it was checked
            print(f"{where}: {exc}", file=sys.stderr)
            return None
        if finished:
            passes += 1
            shifted = replayer.offset_ns / 1e9
            say(
                {
                    "event": "pass",
                    "pass": passes,
                    "shift_s": round(shifted, 3),
                    **replayer.counters,
                },
                f"pass {passes} played: {replayer.counters['published']} samples published "
                f"so far, timestamps shifted by {shifted:+.3f} s",
            )
        if not loop:
            break
    return passes
