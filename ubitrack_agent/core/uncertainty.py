"""First-order propagation of 6x6 pose covariances through inversion and concatenation, and
the covariance of noise stated per axis by a sensor.

Parameterisation: left ("global") perturbation ``T = Exp(xi) T_mean`` with
``xi = (phi, rho)``, rotation first (scipy's ``as_exp_coords`` order). The adjoint of
``T = (R, t)`` is then::

    Ad_T = [[R,        0],
            [[t]x R,   R]]        so that  T Exp(xi) T^-1 = Exp(Ad_T xi).

* inversion:      Sigma_inv = Ad_{T^-1} Sigma Ad_{T^-1}^T                      (exact)
* concatenation:  Sigma_12  = Sigma_1 + Ad_{T1} Sigma_2 Ad_{T1}^T      (first order, independent)

Sensors state their noise per axis, and an outside-in tracker's about the measured body's own
origin (its rotation error does not move the body's position): :func:`isotropic_pose_covariance`
and :func:`in_place_covariance` turn such figures into the covariance above.

References: Barfoot & Furgale, "Associating uncertainty with three-dimensional poses for use in
estimation problems", IEEE T-RO 2014; Sola, Deray, Atchuthan, "A micro Lie theory for state
estimation in robotics", arXiv:1812.01537; ``../shared/reference/field-notes.md`` section 9
(Monte Carlo: inversion exact, first-order concatenation within 0.1 % at 1 degree / 1 mm).
"""

from __future__ import annotations

import numpy as np

from ubitrack_agent.core import quaternions

_SKEW_ROWS = np.array([2, 0, 1, 1, 2, 0])
_SKEW_COLS = np.array([1, 2, 0, 2, 0, 1])
_SKEW_COMPONENTS = np.array([0, 1, 2, 0, 1, 2])
_SKEW_SIGNS = np.array([1.0, 1.0, 1.0, -1.0, -1.0, -1.0])
_IDENTITY_QUATERNION = np.array([0.0, 0.0, 0.0, 1.0])


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``[v]x`` (..., 3, 3) with ``[v]x w = v x w``."""
    v = np.asarray(v, dtype=float)
    if v.shape == (3,):  # one vector, written out: a tenth of the indexed form's cost
        x, y, z = v.tolist()
        return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    result = np.zeros((*v.shape[:-1], 3, 3))
    # [v]x = [[0, -z, y], [z, 0, -x], [-y, x, 0]]: entry (r, c) = sign * v[component]
    result[..., _SKEW_ROWS, _SKEW_COLS] = v[..., _SKEW_COMPONENTS] * _SKEW_SIGNS
    return result


def adjoint(q: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Adjoint matrices (..., 6, 6) of transforms ``(q, t)`` for ``xi = (phi, rho)``."""
    rotation = quaternions.to_matrix(q)
    result = np.zeros((*rotation.shape[:-2], 6, 6))
    result[..., :3, :3] = rotation
    result[..., 3:, 3:] = rotation
    result[..., 3:, :3] = skew(t) @ rotation
    return result


def isotropic_pose_covariance(sigma_rotation_rad: float, sigma_translation_m: float) -> np.ndarray:
    """The 6x6 covariance of independent noise with the same standard deviation on each
    rotation axis (radians) and on each translation axis (metres), rotation first."""
    return np.diag([sigma_rotation_rad**2] * 3 + [sigma_translation_m**2] * 3)


LEVER_ARM_M = 1.0
"""The lever arm at which a pose's expected error counts its rotation (:func:`expected_error`)."""


def expected_error(covariance: np.ndarray) -> float:
    """The scalar RMS error (m) a covariance claims, as the planner's ``sigma`` of an edge
    (``docs/planner.md``): for a 6x6 pose covariance the RMS displacement of a point
    :data:`LEVER_ARM_M` from the origin, ``sqrt(trace(Sigma_rho) + trace(Sigma_phi) * 1 m^2)``
    (so a tracker's rotation noise counts: 0.05 degrees is 0.87 mm there); for a position's
    3x3 (or a 2x2 metric) covariance ``sqrt(trace(Sigma))``."""
    covariance = np.asarray(covariance, dtype=float)
    if covariance.shape == (6, 6):
        return float(
            np.sqrt(np.trace(covariance[3:, 3:]) + np.trace(covariance[:3, :3]) * LEVER_ARM_M**2)
        )
    return float(np.sqrt(np.trace(covariance)))


def in_place_covariance(translation: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """The left-perturbation covariance of a pose at ``translation`` whose noise
    ``(phi, rho) ~ N(0, covariance)`` is given in place: rotation about the body's own origin
    plus position noise, ``R = Exp(phi) R_mean`` and ``t = t_mean + rho``.

    In the left convention the same noise is ``(phi, rho + [t]x phi)`` to first order, i.e.
    ``covariance`` transported by the adjoint of the pure translation by ``t``.
    """
    transport = adjoint(_IDENTITY_QUATERNION, translation)
    return _transport(transport, covariance)


def _transport(adj: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    return adj @ covariance @ np.swapaxes(adj, -1, -2)


def invert_covariance(q: np.ndarray, t: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """Covariance of ``T^-1`` given the mean ``T = (q, t)`` and the covariance of ``T``."""
    q_inv = quaternions.conjugate(q)
    t_inv = -quaternions.rotate(q_inv, t)
    return _transport(adjoint(q_inv, t_inv), covariance)


def compose_covariance(
    q1: np.ndarray, t1: np.ndarray, covariance1: np.ndarray, covariance2: np.ndarray
) -> np.ndarray:
    """Covariance of ``T1 T2`` for independent ``T1`` (mean ``(q1, t1)``) and ``T2``."""
    return covariance1 + _transport(adjoint(q1, t1), covariance2)


def interpolate_covariance(
    covariance0: np.ndarray, covariance1: np.ndarray, s: np.ndarray | float
) -> np.ndarray:
    """Covariance of a pose interpolated at ``s`` in [0, 1] between two samples.

    Rule: the linear blend ``(1 - s) Sigma_0 + s Sigma_1``. Both covariances live in the same
    (source) frame under the left perturbation, so no transport is needed. The blend is
    conservative: it is never smaller than ``(1-s)^2 Sigma_0 + s^2 Sigma_1``, the covariance of
    the blend of two independent samples, and the surplus stands for the unmodelled motion
    between the samples. It equals the sample's own covariance at ``s = 0`` and ``s = 1``.
    """
    s = np.asarray(s, dtype=float)[..., None, None]
    return (1.0 - s) * np.asarray(covariance0) + s * np.asarray(covariance1)
