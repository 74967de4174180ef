"""Sensor noise of the simulated A.R.T. tracker.

:func:`perturb_in_place` draws ``(phi, rho) ~ N(0, Sigma)`` (rotation first) and applies it in
place: rotation noise about the body's own origin plus position noise, ``R = Exp(phi) R_true``,
``t = t_true + rho``, as an outside-in tracker's errors behave (its position error does not
grow with the body's distance from the tracker's origin). The covariance of such noise in the
middleware's left-perturbation convention is
:func:`ubitrack_agent.core.uncertainty.in_place_covariance` (first order); ``Sigma`` from per-axis
figures is :func:`ubitrack_agent.core.uncertainty.isotropic_pose_covariance`.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def perturb_in_place(
    rng: np.random.Generator, q: np.ndarray, t: np.ndarray, cov: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``(q, t)`` with rotation noise about its own origin and position noise added."""
    phi, rho = np.split(rng.multivariate_normal(np.zeros(6), cov), 2)
    return (Rotation.from_rotvec(phi) * Rotation.from_quat(q)).as_quat(), np.asarray(t) + rho
