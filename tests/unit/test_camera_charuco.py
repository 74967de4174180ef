"""Camera intrinsics from a ChArUco board (``io/camera/charuco.py``), on views rendered with a
known pinhole camera: the calibration must find that camera again."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ubitrack_agent.cli import main
from ubitrack_agent.io.camera.charuco import (
    MIN_VIEWS,
    Board,
    CalibrationError,
    calibrate,
    find_view,
)
from ubitrack_agent.io.camera.intrinsics import read_intrinsics
from ubitrack_agent.io.static_edges import read_static_edges

BOARD = Board(columns=7, rows=5, square=0.04, marker=0.03)
TRUE_K = np.array([[820.0, 0.0, 330.0], [0.0, 815.0, 236.0], [0.0, 0.0, 1.0]])
SIZE = (640, 480)
PIXELS_PER_SQUARE = 200


def rendered_view(tilt_deg: tuple[float, float, float], distance: float) -> np.ndarray:
    """The board seen by ``TRUE_K`` at ``distance`` (m), rotated by ``tilt_deg`` (xyz Euler)
    about its centre: the printed board warped by the homography ``K [r1 r2 t] S`` (``S``:
    board pixels to metres, OpenCV's board frame: x right, y down, pixel centres at
    integers)."""
    image = BOARD.image(PIXELS_PER_SQUARE)
    metres_per_pixel = BOARD.square / PIXELS_PER_SQUARE
    centre = np.array([BOARD.columns * BOARD.square / 2, BOARD.rows * BOARD.square / 2, 0.0])
    rotation = Rotation.from_euler("xyz", tilt_deg, degrees=True).as_matrix()
    translation = np.array([0.0, 0.0, distance]) - rotation @ centre
    to_metres = np.array(
        [
            [metres_per_pixel, 0, 0.5 * metres_per_pixel],
            [0, metres_per_pixel, 0.5 * metres_per_pixel],
            [0, 0, 1],
        ]
    )
    homography = TRUE_K @ np.column_stack([rotation[:, 0], rotation[:, 1], translation]) @ to_metres
    return cv2.warpPerspective(image, homography, SIZE, flags=cv2.INTER_AREA, borderValue=255)


TILTS = [
    (25, 0, 0),
    (-25, 0, 5),
    (0, 25, 0),
    (0, -25, -5),
    (20, 20, 10),
    (-20, 15, 0),
    (15, -20, 0),
    (0, 0, 0),
]


def test_the_calibration_finds_the_rendering_camera_again():
    views = [find_view(BOARD, rendered_view(tilt, 0.45)) for tilt in TILTS]
    assert all(view is not None and len(view.image_points) >= 20 for view in views)
    calibration = calibrate(views, SIZE)
    found = calibration.intrinsics.matrix
    np.testing.assert_allclose(found[[0, 1], [0, 1]], TRUE_K[[0, 1], [0, 1]], rtol=0.01)
    np.testing.assert_allclose(found[:2, 2], TRUE_K[:2, 2], atol=3.0)
    assert calibration.rms_px < 0.5 and calibration.views == len(TILTS)
    assert calibration.intrinsics.image_size == SIZE
    # The renderer has no distortion: the one found moves no observed corner by a pixel (it
    # fits the rendering's corner error, 0.27 px RMS; its higher coefficients are free where
    # no view reaches the image's corners).
    points = np.concatenate([view.image_points for view in views]).reshape(-1, 1, 2)
    undistorted = cv2.undistortPoints(
        points, found, calibration.intrinsics.distortion, P=found
    ).reshape(-1, 2)
    assert np.max(np.linalg.norm(undistorted - points.reshape(-1, 2), axis=1)) < 1.0


def test_an_image_without_the_board_is_no_view():
    assert find_view(BOARD, np.full((480, 640), 255, np.uint8)) is None
    assert find_view(BOARD, np.zeros((480, 640, 3), np.uint8)) is None


def test_too_few_views_are_refused_with_the_reason():
    view = find_view(BOARD, rendered_view((20, 0, 0), 0.45))
    with pytest.raises(CalibrationError, match=f"at least {MIN_VIEWS}"):
        calibrate([view] * (MIN_VIEWS - 1), SIZE)


@pytest.mark.parametrize(
    "columns, rows, square, marker", [(1, 5, 0.04, 0.03), (7, 5, 0.04, 0.04), (7, 5, 0.04, 0)]
)
def test_an_impossible_board_is_refused(columns, rows, square, marker):
    with pytest.raises(ValueError):
        Board(columns, rows, square, marker)


def test_the_command_writes_a_static_edges_file_the_camera_reads(tmp_path, capsys):
    paths = []
    for index, tilt in enumerate(TILTS):
        paths.append(str(tmp_path / f"view{index}.png"))
        cv2.imwrite(paths[-1], rendered_view(tilt, 0.45))
    out = tmp_path / "camera.yaml"
    assert main(["intrinsics", *paths, "--out", str(out)]) == 0
    assert "8 views, RMS reprojection error" in capsys.readouterr().out
    intrinsics = read_intrinsics(out, "C", "IP")
    np.testing.assert_allclose(intrinsics.matrix[0, 0], TRUE_K[0, 0], rtol=0.01)
    _, edges = read_static_edges(out, 0)
    projection = next(e.value for e in edges if e.announcement.type == "3x4")
    np.testing.assert_allclose(projection.matrix[:, :3], intrinsics.matrix)
    assert edges[0].provenance["views"] == 8


def test_the_command_prints_the_board_and_refuses_too_few_views(tmp_path, capsys):
    board = tmp_path / "board.png"
    assert main(["intrinsics", "--print-board", str(board)]) == 0
    assert cv2.imread(str(board)).shape[:2] == (5 * 200, 7 * 200)
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((480, 640), 255, np.uint8))
    assert main(["intrinsics", str(blank), "--out", str(tmp_path / "c.yaml")]) == 1
    assert "0 view(s) of the board" in capsys.readouterr().err
    assert main(["intrinsics", str(blank)]) == 2  # no --out
    assert main(["intrinsics", "--board", "7x5", "--dictionary", "5X5_NOPE"]) == 2
