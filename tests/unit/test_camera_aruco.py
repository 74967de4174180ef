"""ArUco detection on images rendered from the simulated world (bench/marker_images.py): the
detected corners against the simulated camera's projection of the true corners, the names,
and the marker's pose from its corners.

Measured by ``python -m bench.camera_bench`` (OpenCV 5.0, sub-pixel refinement, noise-free
renderings, tilts up to 50 degrees, 0.3-2 m): 0.15-0.26 px RMS and at most 0.46 px per
corner (docs/performance.md); the bound tested is 0.5 px RMS and 0.6 px at most."""

from __future__ import annotations

import numpy as np
import pytest

from bench.marker_images import canonical_marker, marker_world, render, true_corners
from ubitrack_agent.core import CameraIntrinsics, quaternions
from ubitrack_agent.io.camera.aruco import (
    DICTIONARIES,
    corner_features,
    corner_positions,
    detect_markers,
    make_detector,
    marker_frame,
    marker_pose,
)

LENGTH = 0.1


def _detect(world, marker_id=7, dictionary="4X4_50"):
    image = render(world, "IP", {"M": marker_id}, LENGTH, 0, dictionary)
    return image, detect_markers(image, make_detector(dictionary))


@pytest.mark.parametrize(
    "distance, tilt, spin", [(0.3, 0, 0), (0.5, 30, 17), (0.8, 50, -40), (1.2, 0, 90)]
)
def test_detected_corners_match_the_projected_truth(distance, tilt, spin):
    world = marker_world(distance, tilt, spin, offset=(0.03, -0.02))
    truth, visible = true_corners(world, "IP", "M", LENGTH, 0)
    _, found = _detect(world)
    assert visible and [marker.id for marker in found] == [7]
    errors = np.linalg.norm(found[0].corners - truth, axis=1)
    assert np.sqrt(np.mean(errors**2)) < 0.5 and errors.max() < 0.6


def test_the_corner_order_is_arucos_clockwise_from_top_left():
    # Facing the camera upright, the printed top-left corner is the image's top-left one.
    _, found = _detect(marker_world(0.5, 0))
    corners = found[0].corners
    assert corners[0, 0] < corners[1, 0] and corners[0, 1] < corners[3, 1]
    assert np.allclose(corners[2] - corners[1], corners[3] - corners[0], atol=1.0)


def test_other_dictionaries_and_an_empty_image():
    _, found = _detect(marker_world(0.5, 20), marker_id=3, dictionary="APRILTAG_36H11")
    assert [marker.id for marker in found] == [3]
    blank = np.full((480, 640), 255, dtype=np.uint8)
    assert detect_markers(blank, make_detector()) == []


def test_the_pose_from_the_corners_is_the_worlds():
    world = marker_world(0.6, 35, 10, offset=(0.05, 0.02))
    _, found = _detect(world)
    intrinsics = CameraIntrinsics(0, world.image_planes["IP"].matrix, np.zeros(5))
    pose = marker_pose(found[0].corners, LENGTH, intrinsics, 42)
    rotation, translation = world.pose("C", "M", 0)
    assert pose is not None and pose.timestamp_ns == 42
    assert np.linalg.norm(pose.translation - translation) < 0.002
    relative = quaternions.multiply(pose.rotation, quaternions.conjugate(rotation))
    assert np.degrees(quaternions.angle(relative)) < 1.0


def test_names_and_geometry():
    assert marker_frame(7) == "M7"
    assert corner_features("M7") == ("M7_0", "M7_1", "M7_2", "M7_3")
    corners = corner_positions(0.2)
    assert np.allclose(corners[0], [-0.1, 0.1, 0.0]) and np.allclose(corners[2], [0.1, -0.1, 0.0])
    assert {"4X4_50", "6X6_250", "APRILTAG_36H11"} <= set(DICTIONARIES)


def test_detector_parameters_are_set_by_name_and_checked():
    detector = make_detector(parameters={"cornerRefinementWinSize": 3})
    assert detector.getDetectorParameters().cornerRefinementWinSize == 3
    with pytest.raises(ValueError, match="unknown ArUco dictionary"):
        make_detector("5X5_7")
    with pytest.raises(ValueError, match="no field 'nonsense'"):
        make_detector(parameters={"nonsense": 1})
    with pytest.raises(ValueError, match="takes a whole number"):
        make_detector(parameters={"cornerRefinementWinSize": 2.5})


def test_the_renderer_needs_a_distortion_free_camera():
    world = marker_world(0.5, 0)
    plane = world.image_planes["IP"]
    object.__setattr__(plane, "distortion", np.array([0.1, 0.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match="distortion-free"):
        render(world, "IP", {"M": 7}, LENGTH, 0)
    assert canonical_marker("4X4_50", 7).shape == (192, 192)
