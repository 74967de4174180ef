"""The simulated world: ground truth between any two frames and the camera projection."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ubitrack_agent.core import se3
from ubitrack_agent.sim_trackers.scenario import load_scenario
from ubitrack_agent.sim_trackers.trajectories import LissajousPath
from ubitrack_agent.sim_trackers.world import FixedPlacement, Frame, ImagePlane, World, WorldError

SCENARIO = load_scenario()
WORLD = SCENARIO.world
TIMES = [0, 1_234_567_891, 17_000_000_000, 1_700_000_000_123_456_789]


def _close(a, b, atol=1e-9):
    (qa, ta), (qb, tb) = a, b
    assert min(np.abs(qa - qb).max(), np.abs(qa + qb).max()) < atol
    np.testing.assert_allclose(ta, tb, atol=atol)


@pytest.mark.parametrize("t", TIMES)
def test_any_two_frames_compose_and_invert_consistently(t):
    names = sorted(WORLD.frames)
    for a in names:
        _close(WORLD.pose(a, a, t), (np.array([0, 0, 0, 1.0]), np.zeros(3)))
        for b in names:
            _close(WORLD.pose(b, a, t), se3.invert(*WORLD.pose(a, b, t)))
            for c in ("ART", "C", "F3"):
                _close(WORLD.pose(a, c, t), se3.compose(*WORLD.pose(a, b, t), *WORLD.pose(b, c, t)))


def test_poses_follow_the_placements():
    t = 5_000_000_000
    q, position = LissajousPath(
        centre=(0.7, 0.0, 1.65),
        amplitude=(0.6, 0.5),
        frequency=(0.05, 0.1),
        look_at=(2.6, 0.0, 1.3),
    ).pose(t * 1e-9)
    _close(WORLD.pose("ART", "HT", t), (q, position))
    # The marker F1 sits at (0, -0.2, -0.15) in WT, which is turned 180 degrees about z.
    np.testing.assert_allclose(WORLD.pose("WT", "F1", t)[1], [0.0, -0.20, -0.15])
    np.testing.assert_allclose(WORLD.pose("ART", "F1", t)[1], [2.6, 0.20, 1.15], atol=1e-12)


def test_look_at_keeps_the_target_on_the_optical_axis():
    for t in TIMES:
        target = WORLD.pose("HT", "WT", t)[1]
        np.testing.assert_allclose(target[:2], 0.0, atol=1e-9)
        assert target[2] > 1.0
        # x axis horizontal in ART (z up), y axis downwards.
        axes = Rotation.from_quat(WORLD.pose("ART", "HT", t)[0]).as_matrix()
        assert abs(axes[2, 0]) < 1e-9 and axes[2, 1] < 0


def test_static_relations():
    assert WORLD.is_static("C", "HT") and WORLD.is_static("WT", "F1")
    assert WORLD.is_static("ART", "A") and WORLD.is_static("F1", "F5")
    assert not WORLD.is_static("ART", "HT") and not WORLD.is_static("C", "F1")


def test_projection_matches_a_pinhole_by_hand_and_cameras_see_the_markers():
    plane = WORLD.image_planes["IP"]
    for t in range(0, 40_000_000_000, 500_000_000):
        seen = WORLD.project("IP", SCENARIO.camera.features, t)
        assert set(seen) == set(SCENARIO.camera.features)
        for name, pixel in seen.items():
            x = WORLD.pose("C", name, t)[1]
            homogeneous = plane.projection_matrix() @ np.append(x, 1.0)
            np.testing.assert_allclose(pixel, homogeneous[:2] / homogeneous[2], atol=1e-9)


def _single_camera_world(distortion) -> World:
    return World(
        [Frame("W"), Frame("C", "W", FixedPlacement()), Frame("P", "W", FixedPlacement())],
        [
            ImagePlane(
                "I",
                "C",
                np.array([[500.0, 0.0, 320.0], [0.0, 510.0, 240.0], [0.0, 0.0, 1.0]]),
                np.asarray(distortion, dtype=float),
                (640, 480),
            )
        ],
    )


def test_distorted_projection_round_trips_through_undistortion():
    # Iterated to convergence: OpenCV's default five iterations leave ~1e-5 in the corners.
    plane = _single_camera_world([-0.2, 0.05, 0.001, -0.002, 0.0]).image_planes["I"]
    rng = np.random.default_rng(0)
    points = np.column_stack([rng.uniform(-0.5, 0.5, (50, 2)), rng.uniform(1.0, 3.0, 50)])
    pixels, visible = plane.project(points)
    assert visible.sum() > 30
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    normalised = cv2.undistortPoints(
        pixels[visible].reshape(-1, 1, 2),
        plane.matrix,
        plane.distortion,
        None,
        None,
        None,
        criteria,
    )
    np.testing.assert_allclose(
        normalised.reshape(-1, 2), points[visible, :2] / points[visible, 2:], atol=1e-6
    )


def test_points_behind_or_outside_the_image_are_not_visible():
    plane = _single_camera_world([]).image_planes["I"]
    _, visible = plane.project(np.array([[0, 0, 1.0], [0, 0, -1.0], [5.0, 0, 1.0], [0, 0, 0.0]]))
    assert visible.tolist() == [True, False, False, False]


@pytest.mark.parametrize(
    ("frames", "message"),
    [
        ([Frame("A"), Frame("B")], "exactly one root"),
        ([Frame("A"), Frame("B", "X", FixedPlacement())], "unknown parent"),
        ([Frame("A"), Frame("A")], "defined twice"),
        (
            [Frame("R"), Frame("A", "B", FixedPlacement()), Frame("B", "A", FixedPlacement())],
            "cycle",
        ),
    ],
)
def test_bad_trees_are_rejected(frames, message):
    with pytest.raises(WorldError, match=message):
        World(frames)


def test_unknown_frames_are_named():
    with pytest.raises(WorldError, match="unknown frame 'nope'"):
        WORLD.pose("ART", "nope", 0)
