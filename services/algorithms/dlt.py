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

from ._checks import as_points, require_spread, same_count
from .auxiliary import compose_projection, decompose_projection
from .estimate import PoseEstimate


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
    object_points: np.ndarray, image_points: np.ndarray, refine: bool = True
) -> np.ndarray:
    """The 3x4 projection ``P`` mapping object points (N x 3) to pixels (N x 2), N >= 6.

    The result is scaled so that ``P = K [R | t]`` with ``K[2, 2] = 1`` and ``det(R) = +1``.
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
        camera_matrix, pose = _minimise_reprojection(obj, img, camera_matrix, pose)
    return compose_projection(camera_matrix, pose)


def _unpack(params: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    fx, skew, cx, fy, cy = params[:5]
    camera_matrix = np.array([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return camera_matrix, Rotation.from_rotvec(params[5:8]).as_matrix(), params[8:]


def _minimise_reprojection(
    obj: np.ndarray, img: np.ndarray, camera_matrix: np.ndarray, pose: PoseEstimate
) -> tuple[np.ndarray, PoseEstimate]:
    def residuals(params: np.ndarray) -> np.ndarray:
        k, rotation, translation = _unpack(params)
        projected = (obj @ rotation.T + translation) @ k.T
        return (projected[:, :2] / projected[:, 2:] - img).ravel()

    start = np.concatenate(
        (
            camera_matrix[[0, 0, 0, 1, 1], [0, 1, 2, 1, 2]],
            Rotation.from_quat(pose.rotation).as_rotvec(),
            pose.translation,
        )
    )
    method = "lm" if 2 * len(obj) >= len(start) else "trf"
    result = least_squares(residuals, start, method=method, x_scale="jac")
    k, rotation, translation = _unpack(result.x)
    return k, PoseEstimate(Rotation.from_matrix(rotation).as_quat(), translation)
