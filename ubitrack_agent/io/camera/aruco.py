"""ArUco markers in an image, pure: OpenCV's detector, the corners' names and geometry, and a
marker's pose from its corners.

* **Detection** is OpenCV's ``cv2.aruco.ArucoDetector(dictionary, detectorParams)`` and its
  ``detectMarkers(image) -> corners, ids, rejectedImgPoints`` (``objdetect`` module, OpenCV
  4.7 and later): per marker its id and its four corners in pixels, in ArUco's order,
  clockwise from the printed marker's top-left corner (0 top-left, 1 top-right,
  2 bottom-right, 3 bottom-left; pixel centres at integer coordinates, as
  ``cv2.projectPoints``). The dictionary is one of ``cv2.aruco.getPredefinedDictionary``'s
  (:data:`DICTIONARIES`, by name without ``DICT_``); the ``cv2.aruco.DetectorParameters`` are
  OpenCV's defaults with sub-pixel corner refinement (``CORNER_REFINE_SUBPIX``), and any of
  its fields can be set by name. The detector does not undistort: corners are in the raw
  (distorted) image, as the simulated camera's features are.
* **Names.** Marker ``id`` is the SRG frame ``M<id>`` unless mapped to another name, and its
  corner ``k`` the feature ``<marker frame>_<k>`` (marker 7: ``M7_0`` .. ``M7_3``).
* **Geometry.** The marker's frame is OpenCV's for ``SOLVEPNP_IPPE_SQUARE``: origin at the
  marker's centre, x to the right and y up on the printed marker, z out of the paper; corner
  ``k`` of a marker of side ``length`` lies at :func:`corner_positions` ``[k]``.
* **Pose** of a marker in the camera's frame: ``cv2.solvePnP`` with ``SOLVEPNP_IPPE_SQUARE``
  on its four corners, the intrinsic matrix and the distortion coefficients.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import NamedTuple

import cv2
import numpy as np

from ubitrack_agent.core import CameraIntrinsics, Pose, quaternions

DICTIONARIES: dict[str, int] = {
    name.removeprefix("DICT_"): getattr(cv2.aruco, name)
    for name in dir(cv2.aruco)
    if name.startswith("DICT_") and name.isupper()
}
"""OpenCV's predefined ArUco dictionaries by name without ``DICT_``: ``4X4_50``,
``6X6_250``, ``APRILTAG_36H11``, ..."""

DEFAULT_DICTIONARY = "4X4_50"
"""OpenCV's default dictionary: 50 markers of 4x4 bits, large cells, easy to print."""

CORNERS = 4


class DetectedMarker(NamedTuple):
    """One marker found in an image: its id and its corners (4 x 2 pixels, ArUco's order)."""

    id: int
    corners: np.ndarray


def dictionary_by_name(dictionary: str) -> cv2.aruco.Dictionary:
    """OpenCV's predefined dictionary ``dictionary`` (named without ``DICT_``); ``ValueError``
    for an unknown one."""
    if dictionary not in DICTIONARIES:
        raise ValueError(f"unknown ArUco dictionary {dictionary!r}; known: {sorted(DICTIONARIES)}")
    return cv2.aruco.getPredefinedDictionary(DICTIONARIES[dictionary])


def make_detector(
    dictionary: str = DEFAULT_DICTIONARY, parameters: Mapping[str, float] | None = None
) -> cv2.aruco.ArucoDetector:
    """An ``ArucoDetector`` for the named dictionary, with sub-pixel corner refinement and the
    ``DetectorParameters`` fields in ``parameters`` set (e.g. ``{"cornerRefinementWinSize":
    3}``); ``ValueError`` for an unknown dictionary or field, or a value OpenCV refuses."""
    known = dictionary_by_name(dictionary)
    settings = cv2.aruco.DetectorParameters()
    settings.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    for name, value in (parameters or {}).items():
        if name.startswith("_") or not hasattr(settings, name) or callable(getattr(settings, name)):
            raise ValueError(f"cv2.aruco.DetectorParameters has no field {name!r}")
        kind = type(getattr(settings, name))
        if kind is not float and value != int(value):
            raise ValueError(f"DetectorParameters.{name} takes a whole number, got {value!r}")
        try:
            setattr(settings, name, kind(value))
        except (TypeError, ValueError, cv2.error) as exc:
            raise ValueError(f"DetectorParameters.{name} = {value!r}: {exc}") from None
    return cv2.aruco.ArucoDetector(known, settings)


def detect_markers(image: np.ndarray, detector: cv2.aruco.ArucoDetector) -> list[DetectedMarker]:
    """The markers ``detector`` finds in ``image`` (8-bit grey or BGR), in OpenCV's order; an
    id printed twice is listed twice. ``cv2.error`` for an image OpenCV cannot read."""
    corners, ids, _ = detector.detectMarkers(image)
    if ids is None:
        return []
    return [
        DetectedMarker(int(marker_id), np.asarray(points, dtype=float).reshape(CORNERS, 2))
        for marker_id, points in zip(ids.ravel(), corners, strict=True)
    ]


def marker_frame(marker_id: int) -> str:
    """The default SRG frame of marker ``marker_id``: ``M<id>``."""
    return f"M{marker_id}"


def corner_features(frame: str) -> tuple[str, ...]:
    """The SRG features of a marker's corners, in ArUco's order: ``<frame>_0`` .. ``_3``."""
    return tuple(f"{frame}_{k}" for k in range(CORNERS))


def corner_positions(length: float) -> np.ndarray:
    """The corners (4 x 3, metres) of a marker of side ``length`` in its own frame, in ArUco's
    order (OpenCV's object points for ``SOLVEPNP_IPPE_SQUARE``)."""
    half = length / 2.0
    return np.array(
        [[-half, half, 0.0], [half, half, 0.0], [half, -half, 0.0], [-half, -half, 0.0]]
    )


def marker_pose(
    corners: np.ndarray, length: float, intrinsics: CameraIntrinsics, timestamp_ns: int
) -> Pose | None:
    """The pose of a marker of side ``length`` in the camera's frame from its four image
    corners (``cv2.solvePnP``, ``SOLVEPNP_IPPE_SQUARE``), ``None`` if OpenCV finds none."""
    ok, rvec, tvec = cv2.solvePnP(
        corner_positions(length),
        np.asarray(corners, dtype=float).reshape(CORNERS, 1, 2),
        intrinsics.matrix,
        intrinsics.distortion,
        flags=cv2.SOLVEPNP_IPPE_SQUARE,
    )
    if not ok or not (np.all(np.isfinite(rvec)) and np.all(np.isfinite(tvec))):
        return None
    matrix, _ = cv2.Rodrigues(rvec)
    return Pose(timestamp_ns, quaternions.from_matrix(matrix), tvec.ravel())
