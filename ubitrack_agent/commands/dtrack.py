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
import sys

from ubitrack_agent.commands.adapter_options import (
    add_adapter_arguments,
    id_frame,
    mapping,
    serve_adapter,
    status_line,
)
from ubitrack_agent.io.dtrack import adapter as dtrack
from ubitrack_agent.net import config


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
        "--body",
        type=id_frame,
        action="append",
        default=[],
        metavar="ID=FRAME",
        help="map a DTrack body id (6d or 6di, from 0) to a frame (repeatable)",
    )
    parser.add_argument(
        "--marker",
        type=id_frame,
        action="append",
        default=[],
        metavar="ID=FRAME",
        help="map a DTrack single-marker id (from 1) to a frame (repeatable)",
    )
    parser.add_argument(
        "--tool",
        type=id_frame,
        action="append",
        default=[],
        metavar="ID=FRAME",
        help="map a DTrack measurement-tool id (6dmt/6dmt2, from 0) to a frame (repeatable)",
    )
    parser.add_argument(
        "--flystick",
        type=id_frame,
        action="append",
        default=[],
        metavar="ID=FRAME",
        help="map a DTrack Flystick id (6df/6df2, from 0) to a frame, its pose only (repeatable)",
    )
    add_adapter_arguments(
        parser,
        provider="ART",
        system="A.R.T. system",
        tracker_frame=dtrack.DEFAULT_TRACKER_FRAME,
        rate=dtrack.DEFAULT_RATE_HZ,
        sigma_mm=dtrack.DEFAULT_SIGMA_MM,
        sigma_deg=dtrack.DEFAULT_SIGMA_DEG,
        device_timestamps="DTrack's ts2 line (or the receive time minus its latency if ts2 is "
        "over 0.1 s off), else its ts line on this host's UTC day, for a synchronised controller",
        status="datagrams and measurements per second, rejections",
    )
    config.add_arguments(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ubitrack_agent.io.adapter import open_udp_socket, serve_udp
    from ubitrack_agent.net.keys import validate_key_chunks

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
            mapping(args.body, "--body"),
            tuple(args.static),
            mapping(args.marker, "--marker"),
            sigma_mm=args.sigma_mm,
            sigma_deg=args.sigma_deg,
            rate=args.rate,
            timestamps=args.timestamps,
            tools=mapping(args.tool, "--tool"),
            flysticks=mapping(args.flystick, "--flystick"),
        )
    except ValueError as exc:  # config.ConfigError is one too
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    try:
        sock = open_udp_socket(args.bind, args.port)
    except OSError as exc:
        print(f"{prog}: cannot listen on UDP {args.bind}:{args.port}: {exc}", file=sys.stderr)
        return 2

    def silent(received: float) -> str:
        return (
            f"; nothing arrives on UDP {args.bind}:{args.port}: is DTrack sending there?"
            if received == 0
            else ""
        )

    def serve(provider, stop, clock) -> None:
        serve_udp(sock, adapter, provider, stop, args.duration, clock)

    with sock:
        return serve_adapter(
            "dtrack",
            settings,
            args,
            adapter,
            serve,
            status_line("dtrack", adapter, "datagrams", silent),
        )
