"""Sensor noise models shared by the simulators.

Pose noise is a left perturbation ``Exp(xi) T_true`` with ``xi = (phi, rho) ~ N(0, Sigma)``,
the convention of the middleware's 6x6 pose covariance (``docs/architecture.md``), so the
covariance a simulator (or an adapter configured with the same noise) reports is exactly the
noise added.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import RigidTransform, Rotation

from ubitrack_agent.core import ErrorPose


def noise_covariance(sigma_deg: float, sigma_mm: float) -> np.ndarray:
    """Isotropic 6x6 covariance for rotation (degrees) and translation (mm) noise."""
    return np.diag([np.radians(sigma_deg) ** 2] * 3 + [(sigma_mm / 1000.0) ** 2] * 3)


def perturb(
    rng: np.random.Generator, q: np.ndarray, t: np.ndarray, cov: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``(q, t)`` perturbed on the left by ``xi ~ N(0, cov)``."""
    truth = RigidTransform.from_components(t, Rotation.from_quat(q))
    sample = RigidTransform.from_exp_coords(rng.multivariate_normal(np.zeros(6), cov)) * truth
    return sample.rotation.as_quat(), sample.translation


def noisy(
    rng: np.random.Generator, timestamp_ns: int, q: np.ndarray, t: np.ndarray, cov: np.ndarray
) -> ErrorPose:
    """An :class:`ErrorPose` of ``(q, t)`` perturbed on the left with covariance ``cov``."""
    return ErrorPose(timestamp_ns, *perturb(rng, q, t, cov), cov)
