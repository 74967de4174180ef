"""Averaging a static edge over time: the mean of repeated measurements and its covariance.

* :func:`average_poses` - rotation: scipy's ``Rotation.mean`` (the chordal L2 mean, Markley et
  al., "Averaging quaternions", J. Guidance 30(4), 2007); translation: the arithmetic mean.
  Covariance of the mean: the sample covariance of the left residuals
  ``xi_i = Log(T_i T_mean^-1)`` divided by N (independent samples).
* :func:`average_positions` - the arithmetic mean and the sample covariance divided by N.

With N = 1 there is no spread to measure and the covariance is ``None``. With few samples the
covariance is singular (rank <= N - 1) but positive semi-definite, as the core accepts.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ubitrack_agent.services.algorithms._checks import as_points, as_quaternions, same_count
from ubitrack_agent.services.algorithms.estimate import (
    PoseEstimate,
    left_residuals,
    rigid,
    symmetric,
)


def _covariance_of_mean(samples: np.ndarray) -> np.ndarray | None:
    if len(samples) < 2:
        return None
    return symmetric(np.atleast_2d(np.cov(samples.T)) / len(samples))


def average_poses(rotations: np.ndarray, translations: np.ndarray) -> PoseEstimate:
    """Mean of N >= 1 poses (N x 4, N x 3) with the 6x6 covariance of the mean."""
    q = as_quaternions("rotations", rotations)
    t = as_points("translations", translations, 3, 1)
    same_count(rotations=q, translations=t)
    mean_rotation = Rotation.from_quat(q).mean()
    mean = PoseEstimate(mean_rotation.as_quat(canonical=True), t.mean(axis=0))
    residuals = left_residuals(rigid(q, t), rigid(mean.rotation, mean.translation))
    return mean._replace(covariance=_covariance_of_mean(residuals))


def average_positions(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Mean (3,) of N >= 1 positions (N x 3) and the 3x3 covariance of the mean."""
    points = as_points("positions", positions, 3, 1)
    return points.mean(axis=0), _covariance_of_mean(points)
