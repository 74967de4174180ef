"""Multi-tracker fusion: simultaneous pose estimates of one edge combined into one.

:func:`fuse_poses` - inverse-covariance (information) weighting on the manifold. Each estimate
``T_i`` with covariance ``Sigma_i`` is expressed as a left perturbation of a reference pose,
``xi_i = Log(T_i T_ref^-1)``; the information-weighted mean ``(sum W_i)^-1 sum W_i xi_i``
(``W_i = Sigma_i^-1``) moves the reference, ``T_ref <- Exp(xi) T_ref``, until the step
vanishes (Gauss-Newton on SE(3)). The fused covariance is ``(sum W_i)^-1``. Left perturbations
all live in frame A, so the covariances need no transport to first order. Reference:
Barfoot & Furgale, "Associating uncertainty with three-dimensional poses for use in
estimation problems", IEEE T-RO 30(3), 2014, section IV (pose fusion). The maps are the
hand-written float closed forms of :mod:`ubitrack_agent.services.algorithms.tangent` (a few
microseconds per pose, where scipy's ``RigidTransform`` costs 150 us a call on one pose); two
estimates of one edge converge in two or three steps.

For trackers that measure at different times, :mod:`ubitrack_agent.services.algorithms.pose_filter`
fuses each measurement as it arrives instead.
"""

from __future__ import annotations

import numpy as np

from ubitrack_agent.services.algorithms._checks import (
    as_covariances,
    as_points,
    as_quaternions,
    same_count,
)
from ubitrack_agent.services.algorithms.estimate import PoseEstimate, symmetric
from ubitrack_agent.services.algorithms.tangent import PoseSpace

_POSES = PoseSpace()
_CONVERGED = 1e-13


def fuse_poses(
    rotations: np.ndarray,
    translations: np.ndarray,
    covariances: np.ndarray,
    max_iterations: int = 20,
) -> PoseEstimate:
    """The information-weighted mean of M >= 1 pose estimates of the same edge.

    ``rotations`` M x 4 (x, y, z, w), ``translations`` M x 3, ``covariances`` M x 6 x 6
    (left perturbation, positive definite). Returns the fused pose and its covariance.
    """
    q = as_quaternions("rotations", rotations)
    t = as_points("translations", translations, 3, 1)
    count = same_count(rotations=q, translations=t)
    covs = as_covariances("covariances", covariances, count, 6)
    weights = np.linalg.inv(covs)
    information = weights.sum(axis=0)
    covariance = symmetric(np.linalg.inv(information))
    poses = np.concatenate((q, t), axis=1)
    reference = tuple(poses[int(np.argmin(np.trace(covs, axis1=1, axis2=2)))].tolist())
    for _ in range(max_iterations):
        xi = _POSES.logs(poses, reference)
        step = covariance @ np.einsum("mij,mj->i", weights, xi)
        reference = _POSES.exp(step.tolist(), reference)
        if np.linalg.norm(step) < _CONVERGED:
            break
    rotation = np.array(reference[:4])
    return PoseEstimate(
        rotation if rotation[3] >= 0 else -rotation, np.array(reference[4:]), covariance
    )
