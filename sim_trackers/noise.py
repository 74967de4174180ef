"""Sensor noise models shared by the simulators.

Two pose noise models, both with ``(phi, rho) ~ N(0, Sigma)`` (rotation first):

* :func:`perturb`: a left perturbation ``Exp(xi) T_true``, the convention of the middleware's
  6x6 pose covariance (``docs/architecture.md``), so ``Sigma`` is the reported covariance;
* :func:`perturb_in_place`: rotation noise about the body's own origin plus position noise,
  ``R = Exp(phi) R_true``, ``t = t_true + rho``, as an outside-in tracker's errors behave (its
  position error does not grow with the body's distance from the tracker's origin). Its
  covariance in the left convention is :func:`in_place_covariance` (first order).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import RigidTransform, Rotation

from ubitrack_agent.core import ErrorPose
from ubitrack_agent.core.uncertainty import adjoint

IDENTITY_QUATERNION = np.array([0.0, 0.0, 0.0, 1.0])


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


def perturb_in_place(
    rng: np.random.Generator, q: np.ndarray, t: np.ndarray, cov: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``(q, t)`` with rotation noise about its own origin and position noise added."""
    phi, rho = np.split(rng.multivariate_normal(np.zeros(6), cov), 2)
    return (Rotation.from_rotvec(phi) * Rotation.from_quat(q)).as_quat(), np.asarray(t) + rho


def in_place_covariance(t: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Left-perturbation covariance of :func:`perturb_in_place` noise ``cov`` at position
    ``t``: ``rho_left = rho + [t]x phi``, i.e. the adjoint of the translation by ``t``."""
    transport = adjoint(IDENTITY_QUATERNION, t)
    return transport @ cov @ transport.T
