"""``ubitrack dtrack``: A.R.T. DTrack2 ASCII UDP in, SRG edges on zenoh out.

Listens for the datagrams of a real A.R.T. controller (in DTrack, Settings -> Output: send
fr, ts or ts2, 6dcal, 6d or 6di and, as needed, 6dmt/6dmt2, 6df/6df2 and 3d to this host and
port) or of ``ubitrack sim art``, and publishes under provider PROVIDER (docs/simulators.md)
each mapped body, measurement tool and Flystick as a 6D edge TRACKER -> FRAME and each mapped
single marker as a 3D edge. Map every body you need with --body ID=FRAME, using the ids of
DTrack's 6d output (from 0; hybrid bodies of the 6di line use the same ids and mapping),
measurement tools with --tool ID=FRAME and Flysticks with --flystick ID=FRAME (ids from 0;
only their poses: buttons and joysticks are not published), and single markers with --marker
ID=FRAME (ids from 1); at least one mapping is required, and unmapped ids are ignored and
counted. Mark bodies fixed in the room with --static FRAME. Other line types (gl, 6dj, 6dcov,
st, unknown ones) are skipped with one warning per type.

The covariance published with each pose is the noise given by --sigma-mm and --sigma-deg
(per axis, rotation about the body's origin; a 6dmt2 tool's own position covariance replaces
--sigma-mm); the defaults are a conservative guess for a calibrated room-size system, not a
manufacturer's figure: measure yours. Timestamps are the receive time unless --timestamps
device, which uses DTRACK3's ts2 line when it is within 0.1 s of this host's clock (else the
receive time minus its latency) or DTrack's ts line, which needs the controller's clock
synchronised with this host's (NTP or PTP).

Example, the paper's figure-1 setup: ubitrack dtrack --body 0=WT --body 1=HT --static WT.
Every 10 s it prints a status line (datagrams and measurements per second, rejections; --quiet:
none). Runs until SIGINT/SIGTERM or --duration seconds, then logs its counters and exits 0; a bad
option exits 2 with the reason.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable
from typing import Any

from ubitrack_agent.io.dtrack import adapter as dtrack
from ubitrack_agent.net import config
from ubitrack_agent.net.status_line import periodic_status

log = logging.getLogger("ubitrack.dtrack")


def _id_frame(text: str) -> tuple[int, str]:
    ident, sep, frame = text.partition("=")
    if not sep or not ident.isdigit() or not frame:
        raise argparse.ArgumentTypeError(f"expected ID=FRAME like 1=HT, got {text!r}")
    return int(ident), frame


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "dtrack",
        help="receive A.R.T. DTrack2 UDP and publish its bodies as SRG edges",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--bind",
        default="0.0.0.0",
        metavar="ADDRESS",
        help="address to listen on: all interfaces, for a controller on the network "
        "(127.0.0.1 for the simulator alone; default: %(default)s)",
    )
    parser.add_argument(
        "--port",
        type=int,
        default=dtrack.DEFAULT_PORT,
        help="UDP port DTrack sends to (default: %(default)s)",
    )
    parser.add_argument(
        "--provider",
        default="ART",
        help="provider id, one per A.R.T. system (default: %(default)s)",
    )
    parser.add_argument(
        "--tracker-frame",
        default=dtrack.DEFAULT_TRACKER_FRAME,
        help="the tracker's frame, source of every edge (default: %(default)s)",
    )
    parser.add_argument(
        "--body",
        type=_id_frame,
        action="append",
        default=[],
        metavar="ID=FRAME",
        help="map a DTrack body id (6d or 6di, from 0) to a frame (repeatable)",
    )
    parser.add_argument(
        "--static",
        action="append",
        default=[],
        metavar="FRAME",
        help="announce this body's edge as static: fixed in the room (repeatable)",
    )
    parser.add_argument(
        "--marker",
        type=_id_frame,
        action="append",
        default=[],
        metavar="ID=FRAME",
        help="map a DTrack single-marker id (from 1) to a frame (repeatable)",
    )
    parser.add_argument(
        "--tool",
        type=_id_frame,
        action="append",
        default=[],
        metavar="ID=FRAME",
        help="map a DTrack measurement-tool id (6dmt/6dmt2, from 0) to a frame (repeatable)",
    )
    parser.add_argument(
        "--flystick",
        type=_id_frame,
        action="append",
        default=[],
        metavar="ID=FRAME",
        help="map a DTrack Flystick id (6df/6df2, from 0) to a frame, its pose only (repeatable)",
    )
    parser.add_argument(
        "--rate",
        type=float,
        metavar="HZ",
        default=dtrack.DEFAULT_RATE_HZ,
        help="announced frame rate in Hz, for the planner (default: %(default)s)",
    )
    parser.add_argument(
        "--sigma-mm",
        type=float,
        metavar="MM",
        default=dtrack.DEFAULT_SIGMA_MM,
        help="position noise per axis, mm (default: %(default)s)",
    )
    parser.add_argument(
        "--sigma-deg",
        type=float,
        metavar="DEG",
        default=dtrack.DEFAULT_SIGMA_DEG,
        help="rotation noise per axis about the body's origin, degrees (default: %(default)s)",
    )
    parser.add_argument(
        "--timestamps",
        choices=("receive", "device"),
        default="receive",
        help="receive: this host's receive time; device: DTrack's ts2 line (or the receive "
        "time minus its latency if ts2 is over 0.1 s off), else its ts line on this host's UTC "
        "day, for a synchronised controller (default: %(default)s)",
    )
    parser.add_argument(
        "--quiet",
        action="store_true",
        help="no status line (every 10 s: datagrams and measurements per second, rejections)",
    )
    parser.add_argument(
        "--duration",
        type=float,
        metavar="SECONDS",
        help="stop after this many seconds (default: run until stopped)",
    )
    config.add_arguments(parser)
    parser.set_defaults(func=run)


def _id_map(pairs: list[tuple[int, str]], option: str) -> dict[int, str]:
    """``pairs`` as a mapping; ``ValueError`` if an id is given twice."""
    mapping: dict[int, str] = {}
    for ident, frame in pairs:
        if ident in mapping:
            raise ValueError(f"{option} {ident} is given twice ({mapping[ident]}, {frame})")
        mapping[ident] = frame
    return mapping


def _status_line(adapter: Any, args: argparse.Namespace) -> Callable[[], str]:
    """The adapter's one-line status (``net.status_line``): datagrams and measurements per
    second since the last line, rejections so far, and a hint when nothing arrives."""
    from ubitrack_agent.net.status_line import Rate

    datagrams = Rate(lambda: adapter.counters["received"])
    published = Rate(lambda: adapter.counters["published"])

    def line() -> str:
        received = datagrams.per_second()
        silent = (
            f"; nothing arrives on UDP {args.bind}:{args.port}: is DTrack sending there?"
            if received == 0
            else ""
        )
        return (
            f"dtrack: {received:.1f} datagrams/s, {published.per_second():.1f} measurements/s "
            f"published; {adapter.counters['rejected']} datagrams rejected{silent}"
        )

    return line


def run(args: argparse.Namespace) -> int:
    from ubitrack_agent.io.adapter import open_udp_socket, serve_udp
    from ubitrack_agent.io.provider import Provider
    from ubitrack_agent.net.clock import Clock
    from ubitrack_agent.net.keys import KeySpace, validate_key_chunks
    from ubitrack_agent.net.lifecycle import stop_on_signals
    from ubitrack_agent.net.session import open_session

    prog = "ubitrack dtrack"
    if not (args.body or args.marker or args.tool or args.flystick):
        print(
            f"{prog}: no DTrack body mapped to a frame: give --body ID=FRAME for each body "
            "(ids as in DTrack's 6d output, from 0), e.g. --body 0=WT --body 1=HT, "
            "or --tool, --flystick or --marker ID=FRAME for measurement tools, Flysticks "
            "or single markers",
            file=sys.stderr,
        )
        return 2
    try:
        settings = config.from_arguments(args, role="member")
        validate_key_chunks(args.provider, single_chunk=True)
        adapter = dtrack.DTrackAdapter(
            args.tracker_frame,
            _id_map(args.body, "--body"),
            tuple(args.static),
            _id_map(args.marker, "--marker"),
            sigma_mm=args.sigma_mm,
            sigma_deg=args.sigma_deg,
            rate=args.rate,
            timestamps=args.timestamps,
            tools=_id_map(args.tool, "--tool"),
            flysticks=_id_map(args.flystick, "--flystick"),
        )
    except ValueError as exc:  # config.ConfigError is one too
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    try:
        sock = open_udp_socket(args.bind, args.port)
    except OSError as exc:
        print(f"{prog}: cannot listen on UDP {args.bind}:{args.port}: {exc}", file=sys.stderr)
        return 2
    stop = stop_on_signals()
    with (
        sock,
        open_session(settings) as session,
        Provider(
            session, KeySpace(settings.key_prefix), args.provider, adapter.edges, settings.host_name
        ) as provider,
        periodic_status(_status_line(adapter, args), not args.quiet),
    ):
        serve_udp(sock, adapter, provider, stop, args.duration, Clock.of(settings))
    log.info("dtrack counters: %s", dict(adapter.counters))
    return 0
