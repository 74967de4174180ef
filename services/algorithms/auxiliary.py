"""Auxiliary patterns: split a pose into rotation and translation, a projection into intrinsics
and pose (and back).

Covariances: the rotation part of a left-perturbed pose keeps ``Sigma_phi`` (the 3x3 block,
rotation error ``R = Exp(phi) R_mean`` in frame A); the translation ``t = t_mean + phi x t_mean
+ rho`` has covariance ``J Sigma J^T`` with ``J = [-[t]x, I]`` (first order).

Projection decomposition: ``P = K [R | t]`` with ``K`` upper triangular, positive diagonal and
``K[2, 2] = 1``, ``R`` a proper rotation, by RQ decomposition of the left 3x3 block (Hartley &
Zisserman, "Multiple View Geometry", 2nd ed., section 6.2.4). ``P`` is homogeneous; its sign is
chosen so that ``det(M) > 0``, which puts the points in front of the camera at positive depth.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from ubitrack_agent.services.algorithms._checks import (
    as_array,
    as_camera_matrix,
    as_covariances,
    as_quaternions,
)
from ubitrack_agent.services.algorithms.estimate import (
    PoseEstimate,
    from_rotation_matrix,
    point_jacobian,
    symmetric,
)

_SINGULAR = 1e-12


def split_pose(
    rotation: np.ndarray, translation: np.ndarray, covariance: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """``(q, t, cov_rotation, cov_translation)`` of a pose and its optional 6x6 covariance.

    ``cov_rotation`` is over the left rotation perturbation ``phi`` (3x3), ``cov_translation``
    the plain covariance of ``t`` (3x3); both ``None`` without a pose covariance.
    """
    q = as_quaternions("rotation", np.reshape(rotation, (1, -1)))[0]
    t = as_array("translation", translation, (3,))
    if covariance is None:
        return q, t, None, None
    cov = as_covariances("covariance", np.reshape(covariance, (1, 6, 6)), 1, 6)[0]
    jacobian = point_jacobian(t[None])[0]
    return q, t, cov[:3, :3].copy(), symmetric(jacobian @ cov @ jacobian.T)


def compose_projection(camera_matrix: np.ndarray, pose: PoseEstimate) -> np.ndarray:
    """``P = K [R | t]`` (3x4) for intrinsics ``K`` and the pose of the world in the camera."""
    k = as_camera_matrix(camera_matrix)
    return k @ np.column_stack((pose.matrix(), pose.translation))


def decompose_projection(projection: np.ndarray) -> tuple[np.ndarray, PoseEstimate]:
    """Intrinsics ``K`` (3x3) and pose of the world in the camera from ``P = K [R | t]``.

    Raises ``ValueError`` if ``P`` is not a finite 3x4 matrix with a regular left 3x3 block.
    """
    p = as_array("projection", projection, (3, 4))
    p = p / np.max(np.abs(p)) if np.any(p) else p
    determinant = np.linalg.det(p[:, :3])
    if abs(determinant) < _SINGULAR:
        raise ValueError("projection: left 3x3 block is singular (camera at infinity)")
    p = p * np.sign(determinant)
    upper, rotation = scipy.linalg.rq(p[:, :3])
    signs = np.sign(np.diag(upper))
    upper, rotation = upper * signs, signs[:, None] * rotation  # K D, D R with D = D^-1
    translation = np.linalg.solve(upper, p[:, 3])
    return upper / upper[2, 2], from_rotation_matrix(rotation, translation)
