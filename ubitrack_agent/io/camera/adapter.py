"""Camera adapter: images in, the ArUco markers' corners (and poses) as SRG edges out.

A :class:`~ubitrack_agent.io.adapter.SensorAdapter` over frames (``numpy`` images, 8-bit grey
or BGR, as ``cv2.VideoCapture.read`` gives them), following the simulated camera
(:mod:`ubitrack_agent.sim_trackers.sim_camera`) so that the agent's 2D-3D pose estimation consumes
its measurements unchanged:

* **Edges.** Each mapped marker id ``i`` with frame ``M`` (``M<i>`` by default,
  :mod:`.aruco`) gives four dynamic 2D edges ``<image plane> -> M_0 .. M_3``, one per corner
  in ArUco's order, named ``<image plane>_M_k``; each announces as ``sigma`` the metric error
  the pixel noise makes at the working depth, ``sigma_px * depth / f`` (the simulated
  camera's convention, with the depth given rather than simulated). With a camera frame and
  the marker's side length, each marker also gives a dynamic 6D edge ``<camera> -> M``.
* **Conversion.** Per frame, every detected marker with a mapped id gives a
  :class:`~ubitrack_agent.core.Position2D` per corner (pixels of the raw image, covariance
  ``sigma_px^2 I``) and, with poses on, a :class:`~ubitrack_agent.core.Pose` from
  ``cv2.solvePnP`` (:func:`.aruco.marker_pose`; no covariance). All measurements of a frame
  carry the frame's timestamp, the time it was read (the ``receive`` policy: a webcam has no
  clock synchronised with the host's).
* **Counted, never fatal.** A frame that is not an 8-bit image, or that OpenCV refuses, is
  rejected (:class:`~ubitrack_agent.io.adapter.RejectedInput`); a marker id that is not mapped
  (``unmapped_marker_<id>``), an id seen twice in one frame (``duplicate_marker_<id>``, its
  corners are ambiguous) and a pose ``solvePnP`` does not find (``no_pose_<id>``) are ignored
  and counted; :attr:`CameraAdapter.markers_seen` counts the mapped markers published.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping

import cv2
import numpy as np

from ubitrack_agent.core import CameraIntrinsics, Measurement, Position2D
from ubitrack_agent.io.adapter import RejectedInput, SensorAdapter
from ubitrack_agent.io.camera import DEFAULT_DEPTH_M, DEFAULT_SIGMA_PX
from ubitrack_agent.io.camera.aruco import (
    DetectedMarker,
    corner_features,
    detect_markers,
    marker_pose,
)
from ubitrack_agent.io.provider import EdgeAnnouncement

CHANNELS = (1, 3, 4)
"""Channels of the images OpenCV's detector reads: grey, BGR, BGRA."""


def metric_sigma(sigma_px: float, depth_m: float, intrinsics: CameraIntrinsics) -> float:
    """The metric error (m) of ``sigma_px`` pixels at ``depth_m``: ``sigma_px * depth / f``,
    with ``f`` the mean focal length (the simulated camera's convention)."""
    focal = 0.5 * (intrinsics.matrix[0, 0] + intrinsics.matrix[1, 1])
    return sigma_px * depth_m / focal


def check_image(image: object) -> np.ndarray:
    """``image`` if it is an 8-bit grey, BGR or BGRA image; :class:`RejectedInput` else."""
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8:
        kind = getattr(image, "dtype", type(image).__name__)
        raise RejectedInput(f"a frame must be an 8-bit image, got {kind}")
    channels = 1 if image.ndim == 2 else image.shape[-1]
    if image.ndim not in (2, 3) or channels not in CHANNELS or not image.size:
        raise RejectedInput(f"a frame must be grey, BGR or BGRA, got shape {image.shape}")
    return image


class CameraAdapter(SensorAdapter[np.ndarray]):
    """Turns frames into measurements of the mapped markers' corners and poses (see the module
    docstring); ``ValueError`` for an inconsistent configuration."""

    device = "camera"

    def __init__(
        self,
        image_plane: str,
        markers: Mapping[int, str],
        detector: cv2.aruco.ArucoDetector,
        intrinsics: CameraIntrinsics,
        sigma_px: float = DEFAULT_SIGMA_PX,
        depth_m: float = DEFAULT_DEPTH_M,
        rate: float | None = None,
        camera: str | None = None,
        marker_length: float | None = None,
    ) -> None:
        if not markers:
            raise ValueError("no ArUco marker id is mapped to a frame")
        if any(marker_id < 0 for marker_id in markers):
            raise ValueError("ArUco marker ids count from 0")
        if sigma_px <= 0 or depth_m <= 0:
            raise ValueError("the corner noise and the working depth must be > 0")
        if camera is not None and not (marker_length and marker_length > 0):
            raise ValueError("marker poses need the marker's side length (> 0, metres)")
        sigma = metric_sigma(sigma_px, depth_m, intrinsics)
        edges = [
            EdgeAnnouncement(image_plane, feature, "2D", rate=rate, sigma=sigma)
            for frame in markers.values()
            for feature in corner_features(frame)
        ]
        if camera is not None:
            edges += [
                EdgeAnnouncement(camera, frame, "6D", rate=rate) for frame in markers.values()
            ]
        super().__init__(edges)
        self.corner_edges = {
            marker_id: tuple(f"{image_plane}_{feature}" for feature in corner_features(frame))
            for marker_id, frame in markers.items()
        }
        self.pose_edges = (
            {marker_id: f"{camera}_{frame}" for marker_id, frame in markers.items()}
            if camera is not None
            else {}
        )
        self.detector = detector
        self.intrinsics = intrinsics
        self.marker_length = marker_length
        self.covariance = np.eye(2) * sigma_px**2
        self.markers_seen: Counter[int] = Counter()

    def convert(self, raw: np.ndarray, received_ns: int) -> list[tuple[str, Measurement]]:
        image = check_image(raw)
        try:
            found = detect_markers(image, self.detector)
        except cv2.error as exc:
            raise RejectedInput(f"OpenCV cannot read the frame: {exc.err}") from None
        stamp = self.stamp(None, received_ns)
        ids = Counter(marker.id for marker in found)
        measurements: list[tuple[str, Measurement]] = []
        for marker in found:
            if self._mapped(marker.id, ids[marker.id]):
                measurements += self._marker(marker, stamp)
        return measurements

    def _mapped(self, marker_id: int, times_seen: int) -> bool:
        """Whether a detected id is published: mapped, and seen once in its frame."""
        if marker_id not in self.corner_edges:
            self.ignore(
                f"unmapped_marker_{marker_id}", f"ArUco marker id {marker_id} is not mapped"
            )
            return False
        if times_seen > 1:
            self.ignore(
                f"duplicate_marker_{marker_id}",
                f"ArUco marker id {marker_id} seen more than once in a frame (ambiguous)",
            )
            return False
        return True

    def _marker(self, marker: DetectedMarker, stamp: int) -> list[tuple[str, Measurement]]:
        """The corners of one mapped marker and, with poses on, its pose."""
        self.markers_seen[marker.id] += 1
        measurements: list[tuple[str, Measurement]] = [
            (edge, Position2D(stamp, corner, self.covariance))
            for edge, corner in zip(self.corner_edges[marker.id], marker.corners, strict=True)
        ]
        if self.pose_edges and self.marker_length is not None:
            pose = marker_pose(marker.corners, self.marker_length, self.intrinsics, stamp)
            if pose is None:
                self.ignore(f"no_pose_{marker.id}", f"no pose found for marker {marker.id}")
            else:
                measurements.append((self.pose_edges[marker.id], pose))
        return measurements
