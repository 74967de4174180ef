"""3D-3D pose estimation (the absolute orientation problem), with a covariance estimate.

Given N >= 3 corresponding points measured in two frames, ``points_a[i] = R points_b[i] + t``,
find the pose (R, t) of B in A minimising ``sum_i w_i |a_i - R b_i - t|^2``.

The rotation comes from scipy's ``Rotation.align_vectors`` on the centred point sets (the
Kabsch/Umeyama SVD solution, equivalent to Horn's closed form), the translation from the
centroids. References: Horn, "Closed-form solution of absolute orientation using unit
quaternions", JOSA A 4(4), 1987; Umeyama, "Least-squares estimation of transformation
parameters between two point patterns", IEEE PAMI 13(4), 1991.

Covariance: the inverse Fisher information of the same least-squares model with isotropic
noise of standard deviation ``sigma`` on the residual ``a_i - (R b_i + t)`` (for noise
``sigma_a`` on A and ``sigma_b`` on B, ``sigma^2 = sigma_a^2 + sigma_b^2``):
``Sigma = sigma^2 (sum_i w_i J_i^T J_i)^-1`` with ``J_i = [-[y_i]x, I]``, ``y_i = R b_i + t``,
the Jacobian of the left perturbation. Without ``sigma`` it is estimated from the residuals,
``sigma^2 = sum_i w_i |r_i|^2 / (3N - 6)`` (needs N >= 3; with N = 3 the estimate rests on 3
degrees of freedom only).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ubitrack_agent.services.algorithms._checks import (
    as_array,
    as_points,
    positive,
    require_spread,
    same_count,
)
from ubitrack_agent.services.algorithms.estimate import PoseEstimate, point_jacobian, symmetric


def absolute_orientation(
    points_a: np.ndarray,
    points_b: np.ndarray,
    weights: np.ndarray | None = None,
    sigma: float | None = None,
) -> PoseEstimate:
    """Pose of B in A from N >= 3 corresponding points (N x 3 each), with its covariance.

    ``weights`` (N, positive) weight the squared residuals; ``sigma`` is the standard deviation
    of one residual coordinate (unit of the points), estimated from the residuals if omitted.
    Raises ``ValueError`` for bad shapes, NaN, fewer than 3 points or collinear points.
    """
    a = as_points("points_a", points_a, 3, 3)
    b = as_points("points_b", points_b, 3, 3)
    n = same_count(points_a=a, points_b=b)
    w = np.ones(n) if weights is None else as_array("weights", weights, (n,))
    if np.any(w <= 0):
        raise ValueError("weights: must all be positive")
    require_spread("points_a", a, 2, "collinear")
    require_spread("points_b", b, 2, "collinear")

    w_norm = w / w.sum()
    centroid_a = w_norm @ a
    centroid_b = w_norm @ b
    rotation, _ = Rotation.align_vectors(a - centroid_a, b - centroid_b, weights=w)
    translation = centroid_a - rotation.apply(centroid_b)

    transformed = rotation.apply(b) + translation
    if sigma is None:
        residual = a - transformed
        variance = float(w @ np.sum(residual**2, axis=1)) / (3 * n - 6)
    else:
        variance = positive("sigma", sigma) ** 2
    jac = point_jacobian(transformed)
    information = np.einsum("n,nki,nkj->ij", w, jac, jac)
    covariance = symmetric(variance * np.linalg.inv(information))
    return PoseEstimate(rotation.as_quat(canonical=True), translation, covariance)
