"""2D-3D projective calibration: the 3x4 projection matrix from N >= 6 correspondences.

Normalised direct linear transform (Hartley & Zisserman, "Multiple View Geometry", 2nd ed.,
algorithm 7.1): both point sets are translated to their centroid and scaled (mean distance
sqrt(2) in the image, sqrt(3) in space), ``P`` is the singular vector of the 2N x 12 system
with the smallest singular value, then denormalised. With ``refine=True`` (the default) this is
followed by the "gold standard" step of the same algorithm: Levenberg-Marquardt minimisation of
the reprojection error over the 11 parameters of ``P = K [R | t]`` (fx, s, cx, fy, cy, rotation
vector, t) with ``scipy.optimize.least_squares``, the maximum-likelihood estimate for Gaussian
pixel noise.

Why by hand: OpenCV runs a DLT only inside ``solvePnP(ITERATIVE)`` and does not expose it.
The points must not be coplanar (a plane determines only a homography).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from ubitrack_agent.services.algorithms._checks import as_points, require_spread, same_count
from ubitrack_agent.services.algorithms.auxiliary import compose_projection, decompose_projection
from ubitrack_agent.services.algorithms.estimate import PoseEstimate


def normalising_transform(points: np.ndarray) -> np.ndarray:
    """Similarity (D+1 x D+1) moving ``points`` (N x D) to centroid 0, mean distance sqrt(D)."""
    dim = points.shape[1]
    centroid = points.mean(axis=0)
    scale = np.sqrt(dim) / np.mean(np.linalg.norm(points - centroid, axis=1))
    transform = np.eye(dim + 1)
    transform[:dim, :dim] *= scale
    transform[:dim, dim] = -scale * centroid
    return transform


def homogeneous(points: np.ndarray) -> np.ndarray:
    """Points (N x D) with a column of ones appended."""
    return np.column_stack((points, np.ones(len(points))))


def projection_dlt(
    object_points: np.ndarray,
    image_points: np.ndarray,
    refine: bool = True,
    zero_skew: bool = False,
) -> np.ndarray:
    """The 3x4 projection ``P`` mapping object points (N x 3) to pixels (N x 2), N >= 6.

    The result is scaled so that ``P = K [R | t]`` with ``K[2, 2] = 1`` and ``det(R) = +1``.
    ``zero_skew`` makes the refinement keep ``K[0, 1] = 0`` (10 parameters, OpenCV's camera
    model) instead of the general 11-parameter projection.
    Raises ``ValueError`` for bad shapes, NaN, fewer than 6 or coplanar object points.
    """
    obj = as_points("object_points", object_points, 3, 6)
    img = as_points("image_points", image_points, 2, 6)
    same_count(object_points=obj, image_points=img)
    require_spread("object_points", obj, 3, "coplanar")
    require_spread("image_points", img, 2, "collinear")

    t_obj = normalising_transform(obj)
    t_img = normalising_transform(img)
    x = homogeneous(obj) @ t_obj.T
    u = homogeneous(img) @ t_img.T
    zeros = np.zeros_like(x)
    system = np.concatenate(
        (
            np.hstack((x, zeros, -u[:, :1] * x)),
            np.hstack((zeros, x, -u[:, 1:2] * x)),
        )
    )
    normalised = np.linalg.svd(system)[2][-1].reshape(3, 4)
    camera_matrix, pose = decompose_projection(np.linalg.solve(t_img, normalised) @ t_obj)
    if refine:
        camera_matrix, pose = _minimise_reprojection(obj, img, camera_matrix, pose, zero_skew)
    return compose_projection(camera_matrix, pose)


_INTRINSICS = ([0, 0, 0, 1, 1], [0, 1, 2, 1, 2])
"""Indices of (fx, s, cx, fy, cy) in K."""


def _minimise_reprojection(
    obj: np.ndarray,
    img: np.ndarray,
    camera_matrix: np.ndarray,
    pose: PoseEstimate,
    zero_skew: bool,
) -> tuple[np.ndarray, PoseEstimate]:
    rows, columns = _INTRINSICS
    if zero_skew:
        rows, columns = [0, 0, 1, 1], [0, 2, 1, 2]
    n_intrinsics = len(rows)

    def unpack(params: np.ndarray) -> tuple[np.ndarray, Rotation, np.ndarray]:
        k = np.eye(3)
        k[rows, columns] = params[:n_intrinsics]
        rotation = Rotation.from_rotvec(params[n_intrinsics : n_intrinsics + 3])
        return k, rotation, params[n_intrinsics + 3 :]

    def residuals(params: np.ndarray) -> np.ndarray:
        k, rotation, translation = unpack(params)
        projected = (rotation.apply(obj) + translation) @ k.T
        return (projected[:, :2] / projected[:, 2:] - img).ravel()

    start = np.concatenate(
        (
            camera_matrix[rows, columns],
            Rotation.from_quat(pose.rotation).as_rotvec(),
            pose.translation,
        )
    )
    method = "lm" if 2 * len(obj) >= len(start) else "trf"
    result = least_squares(residuals, start, method=method, x_scale="jac")
    k, rotation, translation = unpack(result.x)
    return k, PoseEstimate(rotation.as_quat(), translation)
