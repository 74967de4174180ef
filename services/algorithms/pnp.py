"""2D-3D pose estimation (perspective-n-point) with OpenCV's solvePnP family.

Finds the pose of an object O in a camera C (``x_C = R x_O + t``) from N image points of known
object points, for a calibrated camera (intrinsic matrix and OpenCV distortion model).

Method choice by geometry (``method="auto"``):

* 4 points forming a square centred in the z = 0 plane in OpenCV's order -> ``IPPE_SQUARE``;
* other coplanar points -> ``IPPE`` (Collins & Bartoli, "Infinitesimal plane-based pose
  estimation", IJCV 109, 2014);
* general 3D points -> ``SQPNP`` (Terzakis & Lourakis, "A consistently fast and globally
  optimal solution to the perspective-n-point problem", ECCV 2020), which needs no
  initialisation and returns the global minimum of its algebraic cost;

followed by Levenberg-Marquardt refinement of the reprojection error
(``solvePnPRefineLM``), which makes the result the maximum-likelihood estimate for Gaussian
pixel noise. :func:`solve_pnp_ransac` wraps ``solvePnPRansac`` for data with outliers
(Fischler & Bolles 1981) and refines on the inliers.

Methods are referred to by OpenCV's named constants only (``cv2.SOLVEPNP_SQPNP`` ...): their
integer values changed between OpenCV 4 and 5.

Covariance: ``sigma^2 (J^T J)^-1`` with ``J`` the Jacobian of the projected points (through
OpenCV's full camera model, ``projectPoints``' own Jacobian) with respect to the left perturbation
``xi = (phi, rho)`` of the pose, and ``sigma`` the pixel noise (given, or estimated from the
residuals as ``|r|^2 / (2N - 6)``; with N = 3 and no ``pixel_sigma`` there is no covariance).
Given each pixel's 2x2 covariance ``S_i`` instead (``pixel_covariances``, what a camera announces
with its measurements), the covariance of the (unweighted) least-squares estimate is the
sandwich ``(J^T J)^-1 (sum_i J_i^T S_i J_i) (J^T J)^-1``, equal to the first for
``S_i = sigma^2 I``. Prefer known noise to the residuals' estimate: from five points that has
four degrees of freedom, and the pose's covariance it gives is often far too small
(``python -m bench.pnp_ambiguity_bench``, 2,000 views of the figure-1 target at 0.5 px: mean
NEES 12.0, 257 beyond the 3-sigma bound; 5.94 and 6 with the noise known).

Ambiguity: four points (a feature of five hidden) of a nearly planar target can leave two poses
that fit the pixels about equally well, tens of degrees apart (the planar pose ambiguity,
Schweighofer & Pinz 2006): in the 2,000 views above with one of the five features hidden, 24
solutions were more than 10 degrees off (none with all five). With four points and known pixel
noise, the P3P solutions of three of them (AP3P, Ke & Roumeliotis 2017), each refined on all
four, are the rival minima: the best fit is taken, and a pose is refused (``AmbiguousPose``) if
a rival at least :data:`AMBIGUOUS_DEG` away fits within :data:`AMBIGUOUS_CHI2` of it, as a
covariance cannot describe two far-apart poses. Then no pose was more than 10 degrees off, 43
views (2.2 %) were refused, 26 of which the plain solve had right, and the accepted poses' mean
NEES was 5.89. More points than four are not checked (no such case among the views).
"""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from ubitrack_agent.core.uncertainty import skew
from ubitrack_agent.services.algorithms._checks import (
    as_camera_matrix,
    as_distortion,
    as_points,
    positive,
    rank_of_spread,
    require_spread,
    same_count,
)
from ubitrack_agent.services.algorithms.estimate import (
    PoseEstimate,
    from_rotation_matrix,
    symmetric,
)

PnpMethod = Literal["auto", "sqpnp", "ippe", "ippe_square", "epnp", "iterative"]

OPENCV_METHODS: dict[str, int] = {
    "sqpnp": cv2.SOLVEPNP_SQPNP,
    "ippe": cv2.SOLVEPNP_IPPE,
    "ippe_square": cv2.SOLVEPNP_IPPE_SQUARE,
    "epnp": cv2.SOLVEPNP_EPNP,
    "iterative": cv2.SOLVEPNP_ITERATIVE,
}
"""Our method names and OpenCV's constants (looked up by name, never hard-coded numbers)."""

MINIMUM_POINTS = {"sqpnp": 3, "ippe": 4, "ippe_square": 4, "epnp": 4, "iterative": 4}

_SQUARE_CORNERS = np.array([[-1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [1.0, -1.0, 0.0], [-1.0, -1.0, 0.0]])


def is_marker_square(object_points: np.ndarray) -> bool:
    """True for the 4 corners of a square in z = 0 in IPPE_SQUARE's order.

    The order is ``(-s/2, s/2, 0), (s/2, s/2, 0), (s/2, -s/2, 0), (-s/2, -s/2, 0)``.
    """
    if object_points.shape != (4, 3):
        return False
    half = abs(object_points[1, 0])
    return half > 0 and np.allclose(object_points, half * _SQUARE_CORNERS, rtol=0, atol=1e-9)


def choose_method(object_points: np.ndarray) -> str:
    """The solver for this geometry: ``ippe_square``, ``ippe`` (coplanar) or ``sqpnp``."""
    if is_marker_square(object_points):
        return "ippe_square"
    if rank_of_spread(object_points) < 3:
        return "ippe"
    return "sqpnp"


AMBIGUOUS_DEG = 5.0
"""A rival pose closer than this (rotation, degrees) is the same pose."""
AMBIGUOUS_CHI2 = 9.0
"""A rival whose reprojection chi-square exceeds the best's by less than this fits as well."""


class AmbiguousPose(ValueError):
    """Two poses far apart fit the pixels within their noise (module docstring)."""


def _validated(
    object_points: np.ndarray,
    image_points: np.ndarray,
    camera_matrix: np.ndarray,
    dist_coeffs: np.ndarray | None,
    minimum: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    obj = as_points("object_points", object_points, 3, minimum)
    img = as_points("image_points", image_points, 2, minimum)
    same_count(object_points=obj, image_points=img)
    require_spread("object_points", obj, 2, "collinear")
    return obj, img, as_camera_matrix(camera_matrix), as_distortion(dist_coeffs)


def _projected(
    object_points: np.ndarray, pose: PoseEstimate, camera_matrix: np.ndarray, dist: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Image points (N x 2) and their Jacobian (2N x 6) w.r.t. the left perturbation ``xi``.

    OpenCV returns the Jacobian w.r.t. (rvec, tvec); under ``T <- Exp(xi) T`` these change by
    ``d rvec = J_l^-1(rvec) phi`` and ``d tvec = -[t]x phi + rho`` (Sola et al. 2018, eq. 146).
    """
    rvec = Rotation.from_quat(pose.rotation).as_rotvec()
    translation = np.asarray(pose.translation, dtype=float)
    projected, jacobian = cv2.projectPoints(
        np.asarray(object_points, dtype=float), rvec, translation, camera_matrix, dist
    )
    chain = np.zeros((6, 6))
    chain[:3, :3] = _inverse_left_jacobian(rvec)
    chain[3:, :3] = -skew(translation)
    chain[3:, 3:] = np.eye(3)
    return projected.reshape(-1, 2), jacobian[:, :6] @ chain


def _inverse_left_jacobian(rotation_vector: np.ndarray) -> np.ndarray:
    """``J_l^-1`` of SO(3) at ``rotation_vector``."""
    angle = float(np.linalg.norm(rotation_vector))
    cross = skew(rotation_vector)
    if angle < 1e-6:
        return np.eye(3) - 0.5 * cross + cross @ cross / 12.0
    factor = 1.0 / angle**2 - (1.0 + np.cos(angle)) / (2.0 * angle * np.sin(angle))
    return np.eye(3) - 0.5 * cross + factor * cross @ cross


def project(
    object_points: np.ndarray,
    pose: PoseEstimate,
    camera_matrix: np.ndarray,
    dist_coeffs: np.ndarray | None = None,
) -> np.ndarray:
    """Image points (N x 2) of object points seen by a camera at ``pose`` (object in camera)."""
    return _projected(object_points, pose, camera_matrix, as_distortion(dist_coeffs))[0]


def reprojection_covariance(
    object_points: np.ndarray,
    image_points: np.ndarray,
    pose: PoseEstimate,
    camera_matrix: np.ndarray,
    dist_coeffs: np.ndarray | None = None,
    pixel_sigma: float | None = None,
    pixel_covariances: np.ndarray | None = None,
) -> np.ndarray | None:
    """6x6 left-perturbation covariance of a PnP pose for Gaussian pixel noise: i.i.d. of
    ``pixel_sigma``, or of each pixel's covariance (N x 2 x 2), or estimated from the residuals
    (module docstring)."""
    n = len(object_points)
    projected, jacobian = _projected(object_points, pose, camera_matrix, as_distortion(dist_coeffs))
    if pixel_covariances is not None:
        covariances = np.asarray(pixel_covariances, dtype=float)
        if covariances.shape != (n, 2, 2) or not np.all(np.isfinite(covariances)):
            raise ValueError(f"pixel_covariances: need {n} finite 2x2 matrices")
        normal = jacobian.T @ jacobian
        if np.linalg.cond(normal) > 1e14:
            return None
        rows = jacobian.reshape(n, 2, 6)
        spread = np.einsum("nai,nab,nbj->ij", rows, covariances, rows)
        inverse = np.linalg.inv(normal)
        return symmetric(inverse @ spread @ inverse)
    if pixel_sigma is None:
        if n <= 3:
            return None
        variance = float(np.sum((image_points - projected) ** 2)) / (2 * n - 6)
    else:
        variance = positive("pixel_sigma", pixel_sigma) ** 2
    information = jacobian.T @ jacobian
    if np.linalg.cond(information) > 1e14:
        return None
    return symmetric(variance * np.linalg.inv(information))


def _estimate(
    obj: np.ndarray,
    img: np.ndarray,
    k: np.ndarray,
    dist: np.ndarray,
    rvec: np.ndarray,
    tvec: np.ndarray,
    pixel_sigma: float | None,
    pixel_covariances: np.ndarray | None,
) -> PoseEstimate:
    rotation, _ = cv2.Rodrigues(rvec)
    pose = from_rotation_matrix(rotation, tvec)
    covariance = reprojection_covariance(obj, img, pose, k, dist, pixel_sigma, pixel_covariances)
    return pose._replace(covariance=covariance)


def solve_pnp(
    object_points: np.ndarray,
    image_points: np.ndarray,
    camera_matrix: np.ndarray,
    dist_coeffs: np.ndarray | None = None,
    method: PnpMethod = "auto",
    refine: bool = True,
    pixel_sigma: float | None = None,
    pixel_covariances: np.ndarray | None = None,
) -> PoseEstimate:
    """Pose of the object in the camera from N object points (N x 3) and their pixels (N x 2).

    ``method`` is ``"auto"`` (choose by geometry, see the module docstring) or one of
    :data:`OPENCV_METHODS`; ``refine`` adds Levenberg-Marquardt refinement (on by default).
    The covariance comes from ``pixel_sigma``, else ``pixel_covariances`` (N x 2 x 2), else
    the residuals (module docstring).
    Raises ``ValueError`` for bad shapes, NaN, too few or collinear points, a method that does
    not fit the geometry, or when OpenCV finds no solution.
    """
    if method != "auto" and method not in OPENCV_METHODS:
        raise ValueError(f"method: unknown {method!r}, use 'auto' or one of {list(OPENCV_METHODS)}")
    obj, img, k, dist = _validated(object_points, image_points, camera_matrix, dist_coeffs, 3)
    chosen = choose_method(obj) if method == "auto" else method
    if len(obj) < MINIMUM_POINTS[chosen]:
        raise ValueError(f"{chosen}: need at least {MINIMUM_POINTS[chosen]} points, got {len(obj)}")
    if chosen == "ippe_square" and not is_marker_square(obj):
        raise ValueError("ippe_square: object points must be a centred square in z = 0")
    if chosen == "ippe" and rank_of_spread(obj) == 3:
        raise ValueError("ippe: object points must be coplanar")
    try:
        found, rvec, tvec = cv2.solvePnP(obj, img, k, dist, flags=OPENCV_METHODS[chosen])
    except cv2.error as exc:
        raise ValueError(f"{chosen}: OpenCV rejected the input ({exc.err})") from None
    if not found:
        raise ValueError(f"{chosen}: no solution found")
    if refine:
        rvec, tvec = cv2.solvePnPRefineLM(obj, img, k, dist, rvec, tvec)
    rvec, tvec = _decided(obj, img, k, dist, (rvec, tvec), pixel_sigma, pixel_covariances)
    return _estimate(obj, img, k, dist, rvec, tvec, pixel_sigma, pixel_covariances)


def _decided(
    obj: np.ndarray,
    img: np.ndarray,
    k: np.ndarray,
    dist: np.ndarray,
    found: tuple[np.ndarray, np.ndarray],
    pixel_sigma: float | None,
    pixel_covariances: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray]:
    """The best fit of four points among ``found`` and the P3P solutions of three of them
    refined on all four; :class:`AmbiguousPose` if another fits as well (module docstring).
    ``found`` as it is for more points than four or unknown pixel noise."""
    if len(obj) != 4 or (pixel_sigma is None and pixel_covariances is None):
        return found
    if pixel_covariances is None:
        weights = np.broadcast_to(np.eye(2) / positive("pixel_sigma", pixel_sigma) ** 2, (4, 2, 2))
    else:
        weights = np.linalg.inv(np.asarray(pixel_covariances, dtype=float))

    def chi2(pose: tuple[np.ndarray, np.ndarray]) -> float:
        projected, _ = cv2.projectPoints(obj, pose[0], pose[1], k, dist)
        residuals = projected.reshape(-1, 2) - img
        return float(np.einsum("na,nab,nb->", residuals, weights, residuals))

    try:
        _, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, img, k, dist, flags=cv2.SOLVEPNP_AP3P)
    except cv2.error:
        rvecs, tvecs = (), ()
    poses = [found] + [
        cv2.solvePnPRefineLM(obj, img, k, dist, r.copy(), t.copy())
        for r, t in zip(rvecs, tvecs, strict=True)
    ]
    fits = sorted((chi2(pose), i) for i, pose in enumerate(poses))
    best_fit, best = fits[0]
    rotation = Rotation.from_rotvec(poses[best][0].ravel())
    for fit, i in fits[1:]:
        apart = np.degrees((Rotation.from_rotvec(poses[i][0].ravel()) * rotation.inv()).magnitude())
        if apart > AMBIGUOUS_DEG and fit - best_fit < AMBIGUOUS_CHI2:
            raise AmbiguousPose(
                f"ambiguous pose: another, {apart:.0f} degrees away, fits the four points as well "
                f"(reprojection chi-square {fit:.1f} against {best_fit:.1f})"
            )
    return poses[best]


def solve_pnp_ransac(
    object_points: np.ndarray,
    image_points: np.ndarray,
    camera_matrix: np.ndarray,
    dist_coeffs: np.ndarray | None = None,
    threshold_px: float = 8.0,
    confidence: float = 0.99,
    iterations: int = 100,
    pixel_sigma: float | None = None,
    pixel_covariances: np.ndarray | None = None,
) -> tuple[PoseEstimate, np.ndarray]:
    """Robust PnP: ``solvePnPRansac`` then LM refinement on the inliers.

    Returns the pose (covariance from the inliers, as :func:`solve_pnp` makes it) and a boolean
    inlier mask (N,). Raises
    ``ValueError`` for bad input or when no consensus set is found.
    """
    obj, img, k, dist = _validated(object_points, image_points, camera_matrix, dist_coeffs, 4)
    threshold = positive("threshold_px", threshold_px)
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence: must be in (0, 1), got {confidence}")
    found, rvec, tvec, inliers = cv2.solvePnPRansac(
        obj,
        img,
        k,
        dist,
        iterationsCount=int(iterations),
        reprojectionError=threshold,
        confidence=float(confidence),
    )
    if not found or inliers is None or len(inliers) < 4:
        raise ValueError("ransac: no consensus set of at least 4 inliers found")
    mask = np.zeros(len(obj), dtype=bool)
    mask[inliers.ravel()] = True
    obj, img = obj[mask], img[mask]
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, k, dist, rvec, tvec)
    inlying = None if pixel_covariances is None else np.asarray(pixel_covariances)[mask]
    rvec, tvec = _decided(obj, img, k, dist, (rvec, tvec), pixel_sigma, inlying)
    return _estimate(obj, img, k, dist, rvec, tvec, pixel_sigma, inlying), mask
