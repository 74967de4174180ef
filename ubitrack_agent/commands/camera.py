"""``ubitrack camera``: a webcam or video file in, ArUco marker corners as SRG edges out.

Reads frames from SOURCE (a video device index, 0 for the first webcam, or a video file, read
at its frame rate) with OpenCV, detects the ArUco markers of --dictionary in each (OpenCV's
ArucoDetector with sub-pixel corner refinement; set any cv2.aruco.DetectorParameters field with
--detector-param NAME=VALUE), and publishes under provider PROVIDER, for each marker mapped
with --marker ID[=FRAME] (frame M<ID> by default), its four corners as 2D edges IMAGE_PLANE ->
FRAME_0 .. FRAME_3 (pixels, ArUco's corner order: top-left, top-right, bottom-right,
bottom-left of the printed marker), all of a frame with the time it was read, as `ubitrack sim
camera` does; with --pose and --marker-length, also each marker's pose as a 6D edge CAMERA ->
FRAME (OpenCV's solvePnP, IPPE_SQUARE). Unmapped ids are ignored and counted.

The intrinsics come from the intrinsics edge CAMERA -> IMAGE_PLANE of the static-edges file
--intrinsics (`ubitrack intrinsics` writes one from a ChArUco board; docs/camera.md). Every 5 s
and at the end it prints a status line: frames per second and markers seen (--quiet: none).
Runs until SIGINT/SIGTERM, --duration seconds or the end of a file, then logs its counters
and exits 0; a bad option, file or source exits 2 with the reason.

Example: ubitrack camera 0 --intrinsics camera.yaml --marker 7 --pose --marker-length 0.05
"""

from __future__ import annotations

import argparse
import logging
import sys
from typing import Any

from ubitrack_agent.core.lines import write_line
from ubitrack_agent.io import camera  # the package alone: no OpenCV yet
from ubitrack_agent.net import config

log = logging.getLogger("ubitrack.camera")


def _marker(text: str) -> tuple[int, str | None]:
    ident, sep, frame = text.partition("=")
    if not ident.isdigit() or (sep and not frame):
        raise argparse.ArgumentTypeError(f"expected ID or ID=FRAME like 7=Target, got {text!r}")
    return int(ident), frame or None


def _parameter(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    try:
        if not (name and sep):
            raise ValueError
        return name, float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected NAME=NUMBER, got {text!r}") from None


def _marker_frames(pairs: list[tuple[int, str | None]]) -> dict[int, str]:
    """Marker id -> frame (``M<id>`` unless named); ``ValueError`` for an id given twice."""
    from ubitrack_agent.io.camera.aruco import marker_frame

    frames: dict[int, str] = {}
    for ident, frame in pairs:
        if ident in frames:
            raise ValueError(f"--marker {ident} is given twice")
        frames[ident] = frame or marker_frame(ident)
    return frames


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "camera",
        help="detect ArUco markers in a webcam or video and publish their corners as 2D edges",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("source", metavar="SOURCE", help="video device index (0) or video file")
    parser.add_argument(
        "--intrinsics",
        required=True,
        metavar="FILE",
        help="static-edges file with the intrinsics edge CAMERA -> IMAGE_PLANE",
    )
    parser.add_argument(
        "--marker",
        type=_marker,
        action="append",
        default=[],
        metavar="ID[=FRAME]",
        help="publish ArUco marker ID as frame FRAME (default M<ID>); repeatable",
    )
    parser.add_argument("--camera-frame", default="C", help="camera frame (default: %(default)s)")
    parser.add_argument("--image-plane", default="IP", help="image plane (default: %(default)s)")
    parser.add_argument("--provider", default="webcam", help="provider id (default: %(default)s)")
    parser.add_argument(
        "--dictionary",
        default="4X4_50",
        help="ArUco dictionary, without DICT_ (default: %(default)s)",
    )
    parser.add_argument(
        "--detector-param",
        type=_parameter,
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="set a cv2.aruco.DetectorParameters field, e.g. cornerRefinementWinSize=3",
    )
    parser.add_argument(
        "--pose", action="store_true", help="also publish each marker's pose CAMERA -> FRAME"
    )
    parser.add_argument(
        "--marker-length", type=float, metavar="M", help="printed marker side in metres (--pose)"
    )
    parser.add_argument(
        "--sigma-px",
        type=float,
        default=camera.DEFAULT_SIGMA_PX,
        help="corner noise per axis in pixels (default: %(default)s)",
    )
    parser.add_argument(
        "--depth",
        type=float,
        default=camera.DEFAULT_DEPTH_M,
        metavar="M",
        help="working distance for the announced metric sigma (default: %(default)s)",
    )
    parser.add_argument(
        "--rate",
        type=float,
        metavar="HZ",
        help="announced rate (default: the source's, if it tells)",
    )
    parser.add_argument("--duration", type=float, metavar="SECONDS", help="stop after this long")
    parser.add_argument("--quiet", action="store_true", help="no periodic status line")
    config.add_arguments(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ubitrack_agent.io.camera import capture

    prog = "ubitrack camera"
    try:
        source = capture.open_capture(args.source)
    except OSError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    try:
        source_rate = capture.frame_rate(source)
        settings, adapter = _configure(args, args.rate or source_rate)
        capture.check_frame_size(source, adapter.intrinsics)
        _serve(args, settings, adapter, source, source_rate)
    except ValueError as exc:  # ConfigError and StaticEdgesError are ValueErrors too
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    finally:
        source.release()
    log.info("camera counters: %s", dict(adapter.counters))
    return 0


def _configure(args: argparse.Namespace, rate: float | None) -> tuple[config.Settings, Any]:
    """The settings and the camera adapter the options describe, announcing ``rate``;
    ``ValueError`` saying what is wrong."""
    from ubitrack_agent.io.camera import aruco
    from ubitrack_agent.io.camera.adapter import CameraAdapter
    from ubitrack_agent.io.camera.intrinsics import read_intrinsics
    from ubitrack_agent.net.keys import validate_key_chunks

    if not args.marker:
        raise ValueError("no marker mapped: give --marker ID for each printed marker, e.g. 7")
    if args.pose and args.marker_length is None:
        raise ValueError("--pose needs --marker-length (the printed side, metres)")
    settings = config.from_arguments(args, role="member")
    validate_key_chunks(args.provider, single_chunk=True)
    adapter = CameraAdapter(
        args.image_plane,
        _marker_frames(args.marker),
        aruco.make_detector(args.dictionary, dict(args.detector_param)),
        read_intrinsics(args.intrinsics, args.camera_frame, args.image_plane),
        sigma_px=args.sigma_px,
        depth_m=args.depth,
        rate=rate,
        camera=args.camera_frame if args.pose else None,
        marker_length=args.marker_length,
    )
    return settings, adapter


def _serve(
    args: argparse.Namespace,
    settings: config.Settings,
    adapter: Any,
    source: Any,
    source_rate: float | None,
) -> None:
    """Publish the markers of ``source``'s frames until a signal, the duration or its end; a
    file is read at its frame rate ``source_rate``."""
    from ubitrack_agent.io.camera import capture
    from ubitrack_agent.io.provider import Provider
    from ubitrack_agent.net.clock import Clock
    from ubitrack_agent.net.keys import KeySpace
    from ubitrack_agent.net.lifecycle import stop_on_signals
    from ubitrack_agent.net.session import open_session

    from_device = args.source.isdigit()
    stop = stop_on_signals()
    with (
        open_session(settings) as session,
        Provider(
            session, KeySpace(settings.key_prefix), args.provider, adapter.edges, settings.host_name
        ) as out,
    ):
        out.leave_on_signals(stop)
        capture.serve_capture(
            source,
            adapter,
            out,
            stop,
            from_device=from_device,
            duration_s=args.duration,
            report=None if args.quiet else write_line,
            pace_hz=None if from_device else source_rate,
            clock=Clock.of(settings),
        )
