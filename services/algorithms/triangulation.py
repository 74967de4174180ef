"""Triangulation of 3D points seen by two or more calibrated cameras (n-view).

Given V >= 2 projection matrices ``P_v`` (3x4, pixels from points in the common frame) and the
pixels of N points in every view, find the points:

1. **Linear (DLT)**: for each point, the unit singular vector with the smallest singular value of
   the 2V x 4 system ``[u P_v3 - P_v1; v P_v3 - P_v2]`` whose rows are scaled to unit norm
   (Hartley & Zisserman, "Multiple View Geometry", 2nd ed., section 12.2). All points are
   solved at once with a batched SVD.
2. **Non-linear refinement** (``refine=True``, default): minimise the reprojection error of all
   points with ``scipy.optimize.least_squares`` and the analytic, block-diagonal Jacobian; for
   Gaussian pixel noise this is the maximum-likelihood estimate (HZ section 12.1).

Covariance per point: ``sigma^2 (sum_v J_v^T J_v)^-1`` with ``J_v`` the Jacobian of the
projection in view v: the Cramer-Rao bound at the estimate. ``sigma`` is ``pixel_sigma`` or is
estimated from all residuals, ``|r|^2 / (N (2V - 3))``.

Why by hand: ``cv2.triangulatePoints`` handles exactly two views and only the linear step;
OpenCV's n-view ``sfm`` module is not in the opencv-python wheels.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse
from scipy.optimize import least_squares

from ubitrack_agent.services.algorithms._checks import as_array, positive
from ubitrack_agent.services.algorithms.estimate import symmetric

_PARALLEL_RAYS = 1e-10


class Triangulation(NamedTuple):
    """Triangulated points and their covariances."""

    points: np.ndarray
    """N x 3 points in the frame the projections map from."""
    covariances: np.ndarray
    """N x 3 x 3 covariances (unit of the points squared)."""


def _validated(projections: np.ndarray, image_points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    p = as_array("projections", projections, (None, 3, 4))
    if len(p) < 2:
        raise ValueError(f"projections: need at least 2 views, got {len(p)}")
    x = as_array("image_points", image_points, (len(p), None, 2))
    if x.shape[1] == 0:
        raise ValueError("image_points: need at least 1 point")
    centres = np.array([np.linalg.svd(view)[2][-1] for view in p])
    if np.any(np.abs(centres[:, 3]) < _PARALLEL_RAYS):
        raise ValueError("projections: a camera centre is at infinity")
    centres = centres[:, :3] / centres[:, 3:]
    if np.max(np.linalg.norm(centres - centres[0], axis=1)) < 1e-9 * (
        1.0 + np.linalg.norm(centres[0])
    ):
        raise ValueError("projections: degenerate geometry, all cameras share one centre")
    return p / np.linalg.norm(p, axis=(1, 2), keepdims=True), x


def _project(p: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (V x N x 2) of points (N x 3) and their depths-like third coordinate (V x N)."""
    image = np.einsum("vij,nj->vni", p[:, :, :3], points) + p[:, None, :, 3]
    return image[..., :2] / image[..., 2:], image[..., 2]


def _jacobians(p: np.ndarray, points: np.ndarray) -> np.ndarray:
    """d pixel / d point for every view and point: V x N x 2 x 3."""
    pixels, third = _project(p, points)
    rows = p[:, None, :2, :3] - pixels[..., :, None] * p[:, None, 2:3, :3]
    return rows / third[..., None, None]


def linear_triangulation(p: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Homogeneous linear (DLT) solution for every point, N x 3 (inputs already validated)."""
    rows_u = x[..., 0:1] * p[:, None, 2] - p[:, None, 0]  # V x N x 4
    rows_v = x[..., 1:2] * p[:, None, 2] - p[:, None, 1]
    system = np.concatenate((rows_u, rows_v)).transpose(1, 0, 2)  # N x 2V x 4
    system /= np.linalg.norm(system, axis=2, keepdims=True)
    solution = np.linalg.svd(system)[2][:, -1]
    if np.any(np.abs(solution[:, 3]) < _PARALLEL_RAYS):
        raise ValueError("image_points: degenerate geometry, a point's rays are parallel")
    return solution[:, :3] / solution[:, 3:]


def _refine(p: np.ndarray, x: np.ndarray, points: np.ndarray) -> np.ndarray:
    n_views, n_points = x.shape[:2]
    row = np.arange(2 * n_views * n_points).reshape(n_points, n_views, 2)
    column = np.arange(3 * n_points).reshape(n_points, 3)
    rows = np.broadcast_to(row[..., None], (n_points, n_views, 2, 3)).ravel()
    columns = np.broadcast_to(column[:, None, None, :], (n_points, n_views, 2, 3)).ravel()
    shape = (2 * n_views * n_points, 3 * n_points)

    def residuals(flat: np.ndarray) -> np.ndarray:
        return (_project(p, flat.reshape(-1, 3))[0] - x).transpose(1, 0, 2).ravel()

    def jacobian(flat: np.ndarray) -> scipy.sparse.csr_matrix:
        values = _jacobians(p, flat.reshape(-1, 3)).transpose(1, 0, 2, 3).ravel()
        return scipy.sparse.csr_matrix((values, (rows, columns)), shape=shape)

    result = least_squares(
        residuals, points.ravel(), jac=jacobian, method="trf", x_scale="jac", xtol=1e-14
    )
    return result.x.reshape(-1, 3)


def triangulate_points(
    projections: np.ndarray,
    image_points: np.ndarray,
    refine: bool = True,
    pixel_sigma: float | None = None,
) -> Triangulation:
    """N points (N x 3) from their pixels ``image_points`` (V x N x 2) in V >= 2 views.

    ``projections`` (V x 3 x 4) map points of the common frame to pixels. Raises
    ``ValueError`` for bad shapes, NaN, fewer than 2 views, coincident camera centres or
    parallel rays.
    """
    p, x = _validated(projections, image_points)
    points = linear_triangulation(p, x)
    if refine:
        points = _refine(p, x, points)
    if pixel_sigma is None:
        n_views, n_points = x.shape[:2]
        residual = _project(p, points)[0] - x
        variance = float(np.sum(residual**2)) / (n_points * (2 * n_views - 3))
    else:
        variance = positive("pixel_sigma", pixel_sigma) ** 2
    jac = _jacobians(p, points)
    information = np.einsum("vnki,vnkj->nij", jac, jac)
    return Triangulation(points, symmetric(variance * np.linalg.inv(information)))
