"""``ubitrack dtrack``: A.R.T. DTrack2 ASCII UDP in, SRG edges on zenoh out.

Listens for DTrack datagrams (from ``ubitrack sim art`` or a real A.R.T. controller whose
output is sent to this host and port) and publishes each configured body as a 6D edge
``<tracker> -> <frame>`` of provider ``--provider`` (see ``docs/simulators.md``). Body and
marker ids map to frames through the scenario's ``art`` section unless ``--body``/``--marker``
are given. Runs until SIGINT/SIGTERM or ``--duration`` seconds.
"""

from __future__ import annotations

import argparse
import logging
import sys

from ubitrack_agent.commands.sim import add_common_arguments, prepare

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
        default="127.0.0.1",
        help="address to listen on (0.0.0.0 for "
        "a real controller on the network; default: %(default)s)",
    )
    parser.add_argument("--port", type=int, help="UDP port (default: scenario art.port)")
    parser.add_argument("--provider", help="provider id (default: scenario art.provider)")
    parser.add_argument("--tracker-frame", help="tracker frame (default: scenario art.frame)")
    parser.add_argument(
        "--body",
        type=_id_frame,
        action="append",
        metavar="ID=FRAME",
        help="map a body id to a frame (repeatable; replaces the scenario's)",
    )
    parser.add_argument(
        "--static",
        action="append",
        metavar="FRAME",
        help="announce this body's edge as static (repeatable)",
    )
    parser.add_argument(
        "--marker",
        type=_id_frame,
        action="append",
        metavar="ID=FRAME",
        help="map a single-marker id to a frame (repeatable)",
    )
    parser.add_argument("--sigma-mm", type=float, help="position noise per axis, mm")
    parser.add_argument("--sigma-deg", type=float, help="rotation noise per axis, degrees")
    parser.add_argument(
        "--timestamps",
        choices=("ts", "receive"),
        default="ts",
        help="ts: DTrack's ts field on the host's UTC day; receive: the "
        "receive time (default: %(default)s)",
    )
    add_common_arguments(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from sim_trackers.runtime import provider_session, stop_on_signals
    from ubitrack_agent.io import dtrack_adapter

    prog = "ubitrack dtrack"
    if (prepared := prepare(args, prog)) is None:
        return 2
    scenario, settings = prepared
    art = scenario.art
    bodies = dict(args.body) if args.body else art.bodies
    markers = dict(args.marker) if args.marker else art.markers
    static = tuple(args.static) if args.static is not None else art.static_bodies
    sigma_mm = art.noise.position_mm if args.sigma_mm is None else args.sigma_mm
    sigma_deg = art.noise.rotation_deg if args.sigma_deg is None else args.sigma_deg
    tracker = args.tracker_frame or art.frame
    port = art.port if args.port is None else args.port
    try:
        edges = dtrack_adapter.announcements(
            tracker, bodies, static, markers, art.rate, sigma_mm / 1000.0
        )
    except ValueError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    try:
        sock = dtrack_adapter.open_socket(args.bind, port)
    except OSError as exc:
        print(f"{prog}: cannot listen on UDP {args.bind}:{port}: {exc}", file=sys.stderr)
        return 2
    stop = stop_on_signals()
    with sock, provider_session(settings, args.provider or art.provider, edges) as provider:
        adapter = dtrack_adapter.DTrackAdapter(
            provider, tracker, bodies, markers, sigma_mm, sigma_deg, args.timestamps
        )
        dtrack_adapter.serve(sock, adapter, stop, args.duration)
    log.info("dtrack counters: %s", dict(adapter.counters))
    return 0
