"""``ubitrack intrinsics``: calibrate a camera's intrinsics from views of a ChArUco board and
write them as a static-edges file for ``ubitrack camera`` and the agent.

Print the board first (``--print-board board.png``, the same --board, --square, --marker and
--dictionary; measure the printed square's side and give it as --square). Then show it to the
camera from different angles: SOURCE is a video device index (0: the first webcam), a video
file, or image files. A frame showing at least 6 of the board's chessboard corners is a view;
from a device or a video one view is taken every --every seconds, so move the board between
them. After --views views (or the end of the source) OpenCV's cv2.calibrateCamera computes the
intrinsic matrix and five distortion coefficients (``io/camera/charuco.py``), and OUT gets two
static edges CAMERA -> IMAGE_PLANE: the ``intrinsics`` and the ``3x4`` projection K [I | 0],
with the RMS reprojection error in their provenance. Exit 1 if the views do not determine
the intrinsics, 2 for a bad option or source.

Example: ubitrack intrinsics 0 --board 7x5 --square 0.04 --marker 0.03 --out camera.yaml
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from ubitrack_agent.core.lines import write_line

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
PROVIDER = "camera-calibration"


def _board_size(text: str) -> tuple[int, int]:
    columns, sep, rows = text.partition("x")
    if not (sep and columns.isdigit() and rows.isdigit()):
        raise argparse.ArgumentTypeError(f"expected COLUMNSxROWS like 7x5, got {text!r}")
    return int(columns), int(rows)


def register(subparsers: argparse._SubParsersAction) -> None:
    doc = (__doc__ or "").split("\n\n")
    parser = subparsers.add_parser(
        "intrinsics",
        help="calibrate a camera's intrinsics from a ChArUco board, write a static-edges file",
        description="\n\n".join(doc[1:]),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "source",
        nargs="*",
        metavar="SOURCE",
        help="a video device index, a video file, or image files",
    )
    parser.add_argument("--board", type=_board_size, default=(7, 5), help="squares (default 7x5)")
    parser.add_argument("--square", type=float, default=0.04, help="square side, m (0.04)")
    parser.add_argument("--marker", type=float, default=0.03, help="marker side, m (0.03)")
    parser.add_argument("--dictionary", default="4X4_50", help="ArUco dictionary (4X4_50)")
    parser.add_argument("--views", type=int, default=20, help="views to collect (default 20)")
    parser.add_argument(
        "--every", type=float, default=1.0, help="seconds between views from a device or video"
    )
    parser.add_argument("--camera-frame", default="C", help="camera frame (default C)")
    parser.add_argument("--image-plane", default="IP", help="image plane frame (default IP)")
    parser.add_argument("--out", metavar="FILE", help="static-edges file to write")
    parser.add_argument(
        "--print-board", metavar="PNG", help="write the board as an image to print, and exit"
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import cv2

    from ubitrack_agent.io.camera.charuco import Board, CalibrationError, calibrate

    prog = "ubitrack intrinsics"
    try:
        board = Board(*args.board, args.square, args.marker, args.dictionary)
        board.opencv()  # an unknown dictionary fails here
    except ValueError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    if args.print_board:
        cv2.imwrite(args.print_board, board.image(pixels_per_square=200))
        print(f"{prog}: wrote the board to {args.print_board}; print it, measure the square")
        return 0
    if not args.source or not args.out or args.views < 1 or not args.every >= 0:
        print(f"{prog}: give SOURCE and --out (and --views >= 1, --every >= 0)", file=sys.stderr)
        return 2
    try:
        views, size = _collect(board, args)
    except OSError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    if size is None:
        print(f"{prog}: no image in {' '.join(args.source)}", file=sys.stderr)
        return 2
    try:
        calibration = calibrate(views, size)
    except CalibrationError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 1
    _write(args, calibration)
    matrix = calibration.intrinsics.matrix
    print(
        f"{prog}: {calibration.views} views, RMS reprojection error {calibration.rms_px:.2f} px: "
        f"fx {matrix[0, 0]:.1f}, fy {matrix[1, 1]:.1f}, cx {matrix[0, 2]:.1f}, "
        f"cy {matrix[1, 2]:.1f} px; written to {args.out}"
    )
    return 0


def _collect(board: Any, args: argparse.Namespace) -> tuple[list[Any], tuple[int, int] | None]:
    """The views of ``board`` in the source, and the images' size (None if no image was
    read); ``OSError`` if the source cannot be read or its images differ in size."""
    from ubitrack_agent.io.camera.charuco import find_view

    views, size = [], None
    for image, spaced in _frames(args):
        shape = (image.shape[1], image.shape[0])
        if size is not None and shape != size:
            raise OSError(f"images of {size[0]}x{size[1]} and {shape[0]}x{shape[1]} px mixed")
        size = shape
        view = find_view(board, image) if spaced() else None
        if view is not None:
            views.append(view)
            write_line(f"view {len(views)}: {len(view.image_points)} corners")
            if len(views) >= args.views:
                break
    return views, size


def _frames(args: argparse.Namespace) -> Any:
    """(image, spaced) pairs: each image of the source, and a function saying whether a view
    may be taken from it (``--every`` seconds after the last view from a device or video)."""
    import cv2

    from ubitrack_agent.io.camera.capture import open_capture

    paths = [Path(s) for s in args.source]
    if all(p.suffix.lower() in IMAGE_SUFFIXES for p in paths):
        for path in paths:
            image = cv2.imread(str(path))
            if image is None:
                raise OSError(f"OpenCV cannot read the image {path}")
            yield image, lambda: True
        return
    if len(paths) != 1:
        raise OSError("give one video device or file, or image files")
    capture = open_capture(args.source[0])
    last = [-float("inf")]

    def spaced() -> bool:
        now = time.monotonic()
        if now - last[0] < args.every:
            return False
        last[0] = now
        return True

    try:
        while True:
            ok, image = capture.read()
            if not ok or image is None:
                return
            yield image, spaced
    finally:
        capture.release()


def _write(args: argparse.Namespace, calibration: Any) -> None:
    import numpy as np

    from ubitrack_agent.core.measurements import Projection
    from ubitrack_agent.io.static_edges import StaticEdge, static_announcement, write_static_edges

    intrinsics = calibration.intrinsics
    provenance = {
        "method": "ChArUco board, cv2.calibrateCamera",
        "views": calibration.views,
        "rms_px": round(calibration.rms_px, 4),
        "time": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    projection = Projection(timestamp_ns=0, matrix=np.hstack([intrinsics.matrix, np.zeros((3, 1))]))
    frames = (args.camera_frame, args.image_plane)
    write_static_edges(
        args.out,
        PROVIDER,
        [
            StaticEdge(static_announcement(*frames, "intrinsics"), intrinsics, provenance),
            StaticEdge(static_announcement(*frames, "3x4"), projection, provenance),
        ],
    )
