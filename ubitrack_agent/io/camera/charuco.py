"""A camera's intrinsics from views of a ChArUco board: OpenCV's ChArUco detector and
``cv2.calibrateCamera`` (Zhang, "A flexible new technique for camera calibration", IEEE PAMI
22(11), 2000, with OpenCV's distortion model). Pure: images in, numbers out.

A ChArUco board is a chessboard whose white squares hold ArUco markers: the markers identify
each chessboard corner, so a view that shows only part of the board still gives corners with
known board coordinates (OpenCV's ``CharucoBoard``: origin at the board's top-left corner, x to
the right, y down, z into the board). A view counts if at least :data:`MIN_CORNERS` corners
are found; the calibration needs :data:`MIN_VIEWS` views, seen from different angles (views of
a board facing the camera square on leave the focal length undetermined).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from ubitrack_agent.core import CameraIntrinsics
from ubitrack_agent.io.camera.aruco import dictionary_by_name

MIN_CORNERS = 6
"""Fewest chessboard corners a view must show to count (OpenCV needs at least 4 for a
homography; 6 leave a margin against a bad corner)."""
MIN_VIEWS = 4
"""Fewest views ``calibrate`` accepts (each gives two constraints on the intrinsics)."""


class CalibrationError(ValueError):
    """The views cannot determine the intrinsics; the message says why."""


@dataclass(frozen=True)
class Board:
    """A ChArUco board: ``columns`` x ``rows`` squares of side ``square`` (m), markers of side
    ``marker`` (m) from ``dictionary`` (OpenCV's name without ``DICT_``)."""

    columns: int
    rows: int
    square: float
    marker: float
    dictionary: str = "4X4_50"

    def __post_init__(self) -> None:
        if self.columns < 2 or self.rows < 2:
            raise ValueError(f"a board has at least 2x2 squares, got {self.columns}x{self.rows}")
        if not 0 < self.marker < self.square:
            raise ValueError(
                f"the marker side ({self.marker} m) must be positive and smaller than the "
                f"square's ({self.square} m)"
            )

    def opencv(self) -> cv2.aruco.CharucoBoard:
        return cv2.aruco.CharucoBoard(
            (self.columns, self.rows), self.square, self.marker, dictionary_by_name(self.dictionary)
        )

    def image(self, pixels_per_square: int) -> np.ndarray:
        """The board drawn for printing, without margin (8-bit grey)."""
        size = (self.columns * pixels_per_square, self.rows * pixels_per_square)
        return self.opencv().generateImage(size, marginSize=0)


@dataclass(frozen=True)
class View:
    """The chessboard corners found in one image: board points (N x 3, m) and image points
    (N x 2, px)."""

    board_points: np.ndarray
    image_points: np.ndarray


def find_view(board: Board, image: np.ndarray) -> View | None:
    """The corners of ``board`` in ``image`` (grey or colour, 8 bit), or None if fewer than
    :data:`MIN_CORNERS` are found."""
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    opencv = board.opencv()
    corners, ids, _, _ = cv2.aruco.CharucoDetector(opencv).detectBoard(grey)
    if ids is None or len(ids) < MIN_CORNERS:
        return None
    board_points, image_points = opencv.matchImagePoints(corners, ids)
    return View(board_points.reshape(-1, 3), image_points.reshape(-1, 2))


@dataclass(frozen=True)
class Calibration:
    """The intrinsics and the RMS reprojection error (px) over the ``views`` used."""

    intrinsics: CameraIntrinsics
    rms_px: float
    views: int


def calibrate(views: Sequence[View], image_size: tuple[int, int]) -> Calibration:
    """The intrinsics of the camera that took ``views`` of ``image_size`` (width, height) px:
    ``cv2.calibrateCamera`` with OpenCV's five distortion coefficients (k1, k2, p1, p2, k3);
    :class:`CalibrationError` with fewer than :data:`MIN_VIEWS` views or if OpenCV fails."""
    if len(views) < MIN_VIEWS:
        raise CalibrationError(f"{len(views)} view(s) of the board, at least {MIN_VIEWS} needed")
    try:
        rms, matrix, distortion, _, _ = cv2.calibrateCamera(
            [view.board_points.astype(np.float32) for view in views],
            [view.image_points.astype(np.float32) for view in views],
            image_size,
            None,
            None,
        )
    except cv2.error as exc:
        raise CalibrationError(f"OpenCV could not calibrate: {exc}") from None
    if not np.all(np.isfinite(matrix)) or not np.all(np.isfinite(distortion)):
        raise CalibrationError("OpenCV's solution is not finite: views from more angles needed")
    intrinsics = CameraIntrinsics(
        timestamp_ns=0,
        matrix=matrix,
        distortion=distortion.ravel(),
        image_size=(int(image_size[0]), int(image_size[1])),
    )
    return Calibration(intrinsics, float(rms), len(views))
