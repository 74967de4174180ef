"""``ubitrack natnet``: OptiTrack Motive's NatNet stream in, SRG edges on zenoh out.

Connects to a NatNet server (Motive, Streaming pane: "Broadcast Frame Data" on, rigid bodies
on; or ``ubitrack sim natnet``): sends NAT_CONNECT to its command port until it answers with
its NatNet version (3.0 to 4.x are parsed), asks for the model definitions to learn the rigid
bodies' names, and receives the frames, by multicast (Motive's default: group 239.255.42.99,
data port 1511) or with --unicast (Motive's "Transmission Type: Unicast"; frames then come to
this command's socket, kept alive once a second). It publishes under provider PROVIDER
(docs/natnet.md) each mapped rigid body as a 6D edge TRACKER -> FRAME: map a body by its name
in Motive with --body NAME=FRAME or by its streaming id with --body-id ID=FRAME; at least one
mapping is required; unmapped bodies are ignored and counted. Mark bodies fixed in the room
with --static FRAME. A body is published only when Motive flags it tracked in that frame, and
with --max-marker-error-mm only when its mean marker error is within that limit.

The covariance published with each pose is the noise given by --sigma-mm and --sigma-deg (per
axis, rotation about the body's origin); the defaults are a conservative guess, not a
manufacturer's figure: measure yours. Timestamps are the receive time unless --timestamps
device: the receive time minus NatNet's own latency (transmit minus camera mid-exposure, on
the server's clock), which needs no clock synchronisation.

Example, a Motive on 192.168.0.10 streaming unicast: ubitrack natnet --server 192.168.0.10
--unicast --body WT=WT --body HT=HT --static WT. Every 10 s it prints a status line (packets
and measurements per second, rejections; --quiet: none). Runs until SIGINT/SIGTERM or
--duration seconds, then logs its counters and exits 0; a bad option exits 2 with the reason.
No extra is needed: the adapter uses the standard library only.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from ubitrack_agent.commands.adapter_options import (
    add_adapter_arguments,
    id_frame,
    mapping,
    name_frame,
    serve_adapter,
    status_line,
)
from ubitrack_agent.io.natnet import adapter as natnet
from ubitrack_agent.net import config


def natnet_version(text: str) -> Any:
    """``X.Y`` (or up to ``X.Y.Z.W``) as a NatNet version (``argparse`` type)."""
    from ubitrack_agent.io.natnet.format import NatNetVersion

    parts = text.split(".")
    if not 2 <= len(parts) <= 4 or not all(p.isdigit() and int(p) < 256 for p in parts):
        raise argparse.ArgumentTypeError(f"expected a version like 4.1, got {text!r}")
    return NatNetVersion(*map(int, parts))


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "natnet",
        help="receive OptiTrack Motive's NatNet stream and publish its rigid bodies as SRG edges",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--server",
        default="127.0.0.1",
        metavar="ADDRESS",
        help="the NatNet server's (Motive's) address (default: %(default)s)",
    )
    parser.add_argument(
        "--command-port",
        type=int,
        default=natnet.DEFAULT_COMMAND_PORT,
        help="the server's command port (default: %(default)s)",
    )
    parser.add_argument(
        "--data-port",
        type=int,
        default=natnet.DEFAULT_DATA_PORT,
        help="the multicast data port (default: %(default)s)",
    )
    parser.add_argument(
        "--multicast-group",
        default=natnet.DEFAULT_MULTICAST_GROUP,
        metavar="ADDRESS",
        help="the multicast group frames are sent to (default: %(default)s)",
    )
    parser.add_argument(
        "--unicast",
        action="store_true",
        help="receive the frames by unicast, as Motive's 'Transmission Type: Unicast'",
    )
    parser.add_argument(
        "--interface",
        default="0.0.0.0",
        metavar="ADDRESS",
        help="local address to bind and join the group on (default: %(default)s)",
    )
    parser.add_argument(
        "--natnet-version",
        type=natnet_version,
        metavar="X.Y",
        help="ask the server for this bitstream version, and parse frames at it until the "
        "server's answer says otherwise (default: the server's)",
    )
    parser.add_argument(
        "--body",
        type=name_frame,
        action="append",
        default=[],
        metavar="NAME=FRAME",
        help="map a rigid body by its name in Motive to a frame (repeatable)",
    )
    parser.add_argument(
        "--body-id",
        type=id_frame,
        action="append",
        default=[],
        metavar="ID=FRAME",
        help="map a rigid body by its streaming id to a frame (repeatable)",
    )
    parser.add_argument(
        "--max-marker-error-mm",
        type=float,
        metavar="MM",
        help="leave out a body whose mean marker error exceeds this (default: no limit)",
    )
    add_adapter_arguments(
        parser,
        provider="OptiTrack",
        system="OptiTrack system",
        tracker_frame=natnet.DEFAULT_TRACKER_FRAME,
        rate=natnet.DEFAULT_RATE_HZ,
        sigma_mm=natnet.DEFAULT_SIGMA_MM,
        sigma_deg=natnet.DEFAULT_SIGMA_DEG,
        device_timestamps="the receive time minus NatNet's latency from camera mid-exposure",
        status="packets and measurements per second, rejections",
    )
    config.add_arguments(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ubitrack_agent.io.natnet.link import NatNetLink
    from ubitrack_agent.net.keys import validate_key_chunks

    prog = "ubitrack natnet"
    if not (args.body or args.body_id):
        print(
            f"{prog}: no rigid body mapped to a frame: give --body NAME=FRAME with its name in "
            "Motive (e.g. --body HT=HT) or --body-id ID=FRAME with its streaming id",
            file=sys.stderr,
        )
        return 2
    try:
        settings = config.from_arguments(args, role="member")
        validate_key_chunks(args.provider, single_chunk=True)
        adapter = natnet.NatNetAdapter(
            args.tracker_frame,
            mapping(args.body, "--body"),
            mapping(args.body_id, "--body-id"),
            tuple(args.static),
            sigma_mm=args.sigma_mm,
            sigma_deg=args.sigma_deg,
            rate=args.rate,
            timestamps=args.timestamps,
            max_marker_error_mm=args.max_marker_error_mm,
            version=args.natnet_version,
        )
    except ValueError as exc:  # config.ConfigError is one too
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    try:
        link = NatNetLink(
            args.server,
            args.command_port,
            args.data_port,
            None if args.unicast else args.multicast_group,
            args.interface,
            args.natnet_version,
        )
    except OSError as exc:
        print(f"{prog}: cannot open the NatNet sockets: {exc}", file=sys.stderr)
        return 2

    def hint(_: float) -> str:
        if adapter.server is None:
            return f"; no answer from {args.server}:{args.command_port}: is Motive streaming?"
        return f"; NatNet {adapter.version}"

    def serve(provider, stop, clock) -> None:
        link.serve(adapter, provider, stop, args.duration, clock)

    with link:
        return serve_adapter(
            "natnet",
            settings,
            args,
            adapter,
            serve,
            status_line("natnet", adapter, "packets", hint),
        )
