"""Synthetic camera images of ArUco markers in the simulated world, with their true corners;
shared by the camera benchmark and the unit tests.

A marker is a frame of a :class:`~ubitrack_agent.sim_trackers.world.World`, placed as OpenCV's
marker frame (:mod:`ubitrack_agent.io.camera.aruco`: centre, x right, y up, z out of the paper). Its
true corners are its :func:`~ubitrack_agent.io.camera.aruco.corner_positions` projected through the
image plane's camera model (:meth:`ubitrack_agent.sim_trackers.world.ImagePlane.project`, i.e.
``cv2.projectPoints``). Its image is OpenCV's canonical marker
(``cv2.aruco.generateImageMarker``) warped into the frame (``cv2.warpPerspective``) by the
homography taking the canonical image's outer corners to those projections: exact for an image
plane without distortion (a plane maps to a pinhole image by a homography), which the
renderer therefore requires. It draws at :data:`SUPERSAMPLE` times the resolution and averages
down (``cv2.resize``, ``INTER_AREA``), so an edge's pixel is grey in proportion to the area it
covers, as a sensor's pixel integrates light.
"""

from __future__ import annotations

from collections.abc import Mapping

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from ubitrack_agent.core import se3
from ubitrack_agent.io.camera.aruco import DICTIONARIES, corner_positions
from ubitrack_agent.sim_trackers.world import NEAR_PLANE_M, FixedPlacement, Frame, ImagePlane, World

CAMERA_MATRIX = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]])
"""The synthetic camera of ``bench/synthetic.py``'s protocol: f = 800 px, 640 x 480."""

IMAGE_SIZE = (640, 480)

SUPERSAMPLE = 4
"""Fine pixels per image pixel and axis."""

CELL_PX = 32
"""Pixels per bit cell of the canonical marker image."""

WHITE = 255


def marker_world(
    distance: float, tilt_deg: float, spin_deg: float = 0.0, offset=(0.0, 0.0)
) -> World:
    """A camera ``C`` with image plane ``IP`` (:data:`CAMERA_MATRIX`, no distortion) facing a
    marker frame ``M`` at ``distance`` metres along its axis (plus ``offset`` sideways),
    turned ``spin_deg`` about its own normal and tilted ``tilt_deg`` away from facing the
    camera."""
    facing = Rotation.from_euler("yx", [tilt_deg, 180.0], degrees=True)
    rotation = facing * Rotation.from_euler("z", spin_deg, degrees=True)
    placement = FixedPlacement(tuple(rotation.as_quat()), (*offset, distance))
    return World(
        [Frame("C"), Frame("M", "C", placement)],
        [ImagePlane("IP", "C", CAMERA_MATRIX, np.zeros(5), IMAGE_SIZE)],
    )


def corner_points(
    world: World, plane: ImagePlane, marker: str, length: float, timestamp_ns: int
) -> np.ndarray:
    """The corners (4 x 3, metres, ArUco's order) of marker frame ``marker`` of side
    ``length`` in the camera's frame at ``timestamp_ns``."""
    rotation, translation = world.pose(plane.camera, marker, timestamp_ns)
    return se3.transform_points(rotation, translation, corner_positions(length))


def true_corners(
    world: World, image_plane: str, marker: str, length: float, timestamp_ns: int
) -> tuple[np.ndarray, bool]:
    """The projected corners (4 x 2 px, ArUco's order) of marker frame ``marker`` of side
    ``length`` at ``timestamp_ns``, and whether all four are in view."""
    plane = world.image_planes[image_plane]
    pixels, visible = plane.project(corner_points(world, plane, marker, length, timestamp_ns))
    return pixels, bool(visible.all())


def canonical_marker(dictionary: str, marker_id: int) -> np.ndarray:
    """OpenCV's image of marker ``marker_id`` of ``dictionary``, with a one-cell black border
    and :data:`CELL_PX` pixels per cell."""
    aruco = cv2.aruco.getPredefinedDictionary(DICTIONARIES[dictionary])
    side = (aruco.markerSize + 2) * CELL_PX
    return cv2.aruco.generateImageMarker(aruco, marker_id, side)


def render(
    world: World,
    image_plane: str,
    markers: Mapping[str, int],
    length: float,
    timestamp_ns: int,
    dictionary: str = "4X4_50",
) -> np.ndarray:
    """The grey image (8 bits, white background) the image plane sees at ``timestamp_ns`` of
    the markers ``markers`` (marker frame -> ArUco id) of side ``length``; ``ValueError`` for
    an image plane with distortion."""
    plane = world.image_planes[image_plane]
    if np.any(plane.distortion):
        raise ValueError(f"image plane {image_plane}: the renderer needs a distortion-free camera")
    width, height = plane.image_size
    fine = np.full((height * SUPERSAMPLE, width * SUPERSAMPLE), WHITE, dtype=np.uint8)
    for marker, marker_id in markers.items():
        points = corner_points(world, plane, marker, length, timestamp_ns)
        if np.all(points[:, 2] > NEAR_PLANE_M):  # else the homography folds it into view
            _draw(fine, canonical_marker(dictionary, marker_id), plane.project(points)[0])
    return cv2.resize(fine, (width, height), interpolation=cv2.INTER_AREA)


def _draw(fine: np.ndarray, image: np.ndarray, corners: np.ndarray) -> None:
    """Warp ``image`` into the supersampled frame ``fine`` so that its outer corners land on
    ``corners`` (image pixels); pixel centres are at integers at both resolutions, so an image
    pixel ``u`` is the fine pixel ``SUPERSAMPLE * u + (SUPERSAMPLE - 1) / 2``."""
    side = image.shape[0]
    source = np.array(
        [[-0.5, -0.5], [side - 0.5, -0.5], [side - 0.5, side - 0.5], [-0.5, side - 0.5]]
    )
    target = SUPERSAMPLE * corners + (SUPERSAMPLE - 1) / 2.0
    homography, _ = cv2.findHomography(source, target)  # exact through four points
    mask = cv2.warpPerspective(
        np.full_like(image, WHITE), homography, fine.shape[::-1], flags=cv2.INTER_LINEAR
    )
    warped = cv2.warpPerspective(image, homography, fine.shape[::-1], flags=cv2.INTER_LINEAR)
    weight = mask.astype(float) / WHITE
    fine[:] = np.round(weight * warped + (1.0 - weight) * fine).astype(np.uint8)
