"""Hand-eye calibration ``AX = XB`` from simultaneous poses of a hand and of an eye.

Inputs follow OpenCV's ``calibrateHandEye``: N >= 3 poses of the hand (gripper, or a tracked
body) in the base (robot, or tracker) frame, and the N simultaneous poses of a static target
in the eye (camera) frame. Output: ``X``, the pose of the eye in the hand. From every pair
``i < j`` (all pairs, as OpenCV does, or only consecutive ones) come the relative motions
``A = G_i^-1 G_j`` of the hand and ``B = C_i C_j^-1`` of the eye with ``A X = X B``.

* :func:`hand_eye_park_martin` - Park & Martin, "Robot sensor calibration: solving AX = XB on
  the Euclidean group", IEEE T-RA 10(5), 1994: the rotation aligns the log-rotations
  ``alpha = R_X beta`` in the least-squares sense (here with scipy's ``align_vectors``, the
  same orthogonal Procrustes solution as their ``(M^T M)^-1/2 M^T``), the translation solves
  the stacked linear system ``(R_A - I) t_X = R_X t_B - t_A``.
* :func:`hand_eye_daniilidis` - Daniilidis, "Hand-eye calibration using dual quaternions",
  IJRR 18(3), 1999: rotation and translation together from the null space of the stacked
  dual-quaternion motion equations.
* :func:`hand_eye_calibration` - the estimator to use: one of the two above (all pairs) as the
  starting point, then a joint Gauss-Newton refinement of ``X`` and of the target's pose ``Y``
  in the base over the absolute poses, ``G_i X C_i = Y`` (the ``AX = ZB`` formulation of
  Dornaika & Horaud, "Simultaneous robot-world and hand-eye calibration", IEEE T-RA 14(4),
  1998; Strobl & Hirzinger, "Optimal hand-eye calibration", IROS 2006), weighted by the pose
  covariances. Its output is the joint 12 x 12 first-order covariance of ``(X, Y)``.

Why the absolute poses: every motion pair ``i < j`` reuses poses ``i`` and ``j``, so the
``N (N - 1) / 2`` equations ``A X = X B`` are correlated and their least-squares covariance
would be wrong; the N residuals ``Log(G_i X C_i Y^-1)`` are independent, one per simultaneous
measurement, and their joint solution carries the correct cross terms between ``X`` and
``Y`` (the error of ``X`` is shared by every ``G_i X C_i``, which is why averaging them
alone understates the covariance of ``Y``).

Why by hand: ``cv2.calibrateHandEye`` is not exposed in the OpenCV 5.0.0 Python wheels
(opencv/opencv#29565, fixed for 5.1). The motions need at least two rotations about
non-parallel axes; otherwise ``ValueError``.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from scipy.spatial.transform import RigidTransform, Rotation

from ubitrack_agent.core import quaternions, se3
from ubitrack_agent.core.uncertainty import adjoint, skew
from ubitrack_agent.services.algorithms._checks import (
    as_covariances,
    as_points,
    as_quaternions,
    same_count,
)
from ubitrack_agent.services.algorithms.estimate import PoseEstimate, rigid, symmetric, to_estimate

_PARALLEL_AXES = 1e-6
_MAX_ITERATIONS = 50
_CONVERGED = 1e-12
"""Largest step component (rad or m) at which the refinement stops."""
_VARIANCE_FLOOR = 1e-30
"""Smallest residual variance (rad^2 or m^2) estimated, so that exact data stay solvable."""


def relative_motions(
    hand_rotations: np.ndarray,
    hand_translations: np.ndarray,
    eye_rotations: np.ndarray,
    eye_translations: np.ndarray,
    all_pairs: bool = True,
) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """Validated motion pairs ``((q_A, t_A), (q_B, t_B))``, each M x 4 and M x 3."""
    qg = as_quaternions("hand_rotations", hand_rotations, 3)
    tg = as_points("hand_translations", hand_translations, 3, 3)
    qc = as_quaternions("eye_rotations", eye_rotations, 3)
    tc = as_points("eye_translations", eye_translations, 3, 3)
    n = same_count(hand_rotations=qg, hand_translations=tg, eye_rotations=qc, eye_translations=tc)
    i, j = np.triu_indices(n, 1) if all_pairs else (np.arange(n - 1), np.arange(1, n))
    motion_a = se3.compose(*se3.invert(qg[i], tg[i]), qg[j], tg[j])
    motion_b = se3.compose(qc[i], tc[i], *se3.invert(qc[j], tc[j]))
    return motion_a, motion_b


def _require_two_axes(log_rotations: np.ndarray) -> None:
    singular = np.linalg.svd(log_rotations, compute_uv=False)
    if len(singular) < 2 or singular[1] <= _PARALLEL_AXES * max(singular[0], 1e-300):
        raise ValueError("degenerate motions: need rotations about at least two non-parallel axes")


def hand_eye_park_martin(
    hand_rotations: np.ndarray,
    hand_translations: np.ndarray,
    eye_rotations: np.ndarray,
    eye_translations: np.ndarray,
    all_pairs: bool = True,
) -> PoseEstimate:
    """Pose of the eye in the hand (Park & Martin 1994). See the module docstring."""
    (q_a, t_a), (q_b, t_b) = relative_motions(
        hand_rotations, hand_translations, eye_rotations, eye_translations, all_pairs
    )
    alpha = Rotation.from_quat(q_a).as_rotvec()
    beta = Rotation.from_quat(q_b).as_rotvec()
    _require_two_axes(alpha)
    rotation, _ = Rotation.align_vectors(alpha, beta)
    system = quaternions.to_matrix(q_a) - np.eye(3)
    rhs = rotation.apply(t_b) - t_a
    translation = np.linalg.lstsq(system.reshape(-1, 3), rhs.ravel(), rcond=None)[0]
    return PoseEstimate(rotation.as_quat(canonical=True), translation)


def _left_matrices(q: np.ndarray) -> np.ndarray:
    """``L(q)`` (..., 4, 4) with ``q * p = L(q) p``."""
    return np.swapaxes(quaternions.multiply(q[..., None, :], np.eye(4)), -1, -2)


def _right_matrices(q: np.ndarray) -> np.ndarray:
    """``R(q)`` (..., 4, 4) with ``p * q = R(q) p``."""
    return np.swapaxes(quaternions.multiply(np.eye(4), q[..., None, :]), -1, -2)


def _dual_part(q: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Dual part ``q' = 1/2 t q`` of the unit dual quaternion of ``(q, t)``."""
    return 0.5 * quaternions.multiply(np.concatenate((t, np.zeros((len(t), 1))), axis=1), q)


def hand_eye_daniilidis(
    hand_rotations: np.ndarray,
    hand_translations: np.ndarray,
    eye_rotations: np.ndarray,
    eye_translations: np.ndarray,
    all_pairs: bool = True,
) -> PoseEstimate:
    """Pose of the eye in the hand (Daniilidis 1999). See the module docstring.

    Each motion gives ``a q - q b = 0`` and ``a q' + a' q - q b' - q' b = 0`` for the dual
    quaternions ``a + e a'``, ``b + e b'`` of A, B and ``q + e q'`` of X; the stacked 8M x 8
    system has a two-dimensional null space in which the unit, ``q . q' = 0`` solution is found
    by a quadratic (Daniilidis' eqs. 34-35).
    """
    (q_a, t_a), (q_b, t_b) = relative_motions(
        hand_rotations, hand_translations, eye_rotations, eye_translations, all_pairs
    )
    alpha = Rotation.from_quat(q_a).as_rotvec()
    _require_two_axes(alpha)
    # Daniilidis assumes the signs of a and b agree (equal scalar parts); for rotations near
    # 180 degrees noise makes the scalar parts ambiguous, so the signs are chosen against the
    # sign-free Park-Martin rotation instead: a = q_X b q_X^* up to noise.
    rough, _ = Rotation.align_vectors(alpha, Rotation.from_quat(q_b).as_rotvec())
    mapped = (rough * Rotation.from_quat(q_b) * rough.inv()).as_quat()
    q_b = q_b * np.where(np.sum(q_a * mapped, axis=1) < 0, -1.0, 1.0)[:, None]
    d_a, d_b = _dual_part(q_a, t_a), _dual_part(q_b, t_b)
    rotation_block = _left_matrices(q_a) - _right_matrices(q_b)
    dual_block = _left_matrices(d_a) - _right_matrices(d_b)
    zeros = np.zeros_like(rotation_block)
    system = np.concatenate(
        (
            np.concatenate((rotation_block, zeros), axis=2),
            np.concatenate((dual_block, rotation_block), axis=2),
        ),
        axis=1,
    ).reshape(-1, 8)
    singular, null_space = np.linalg.svd(system, full_matrices=False)[1:]
    if singular[5] <= _PARALLEL_AXES * singular[0]:
        raise ValueError("degenerate motions: the dual-quaternion system has no unique solution")
    (u1, v1), (u2, v2) = null_space[-2].reshape(2, 4), null_space[-1].reshape(2, 4)
    q_real, q_dual = _unit_orthogonal_combination(u1, v1, u2, v2)
    translation = 2.0 * quaternions.multiply(q_dual, quaternions.conjugate(q_real))[:3]
    return PoseEstimate(Rotation.from_quat(q_real).as_quat(canonical=True), translation)


def _unit_orthogonal_combination(
    u1: np.ndarray, v1: np.ndarray, u2: np.ndarray, v2: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``l1 (u1, v1) + l2 (u2, v2)`` with ``|l1 u1 + l2 u2| = 1`` and ``real . dual = 0``.

    The constraint is the homogeneous quadratic form ``l^T Q l = 0`` (Daniilidis' eq. 35); its
    two null directions come from the eigenvectors of ``Q`` (no division by a leading
    coefficient that noise can make arbitrarily small). In exact arithmetic the null space is
    spanned by ``(q, q')`` and ``(0, q)``, so the spurious direction has a vanishing real part;
    of the two, the one whose real part carries the larger share of the 8-vector's norm is kept
    (a scale-free form of Daniilidis' "largest value" rule, which fails when the SVD returns a
    basis vector close to ``(0, q)``).
    """
    cross = 0.5 * (u1 @ v2 + u2 @ v1)
    eigenvalues, eigenvectors = np.linalg.eigh(np.array([[u1 @ v1, cross], [cross, u2 @ v2]]))
    if eigenvalues[0] > 0.0 or eigenvalues[1] < 0.0:
        raise ValueError("degenerate motions: no real dual-quaternion solution")
    low, high = np.sqrt(-eigenvalues[0]), np.sqrt(eigenvalues[1])
    best_real, best_dual, best_share = u1, v1, -1.0
    for sign in (1.0, -1.0):
        l1, l2 = high * eigenvectors[:, 0] + sign * low * eigenvectors[:, 1]
        real, dual = l1 * u1 + l2 * u2, l1 * v1 + l2 * v2
        share = (real @ real) / (real @ real + dual @ dual)
        if share > best_share:
            best_real, best_dual, best_share = real, dual, share
    norm = np.linalg.norm(best_real)
    return best_real / norm, best_dual / norm


class HandEyeSolution(NamedTuple):
    """The result of :func:`hand_eye_calibration`."""

    eye_in_hand: PoseEstimate
    """``X``, the pose of the eye in the hand, with its 6x6 covariance (frame of the hand)."""
    target_in_base: PoseEstimate
    """``Y``, the pose of the target in the base, with its 6x6 covariance (frame of the base);
    it includes the uncertainty of ``X``."""
    cross_covariance: np.ndarray
    """6x6 ``Cov(xi_X, xi_Y)``: the joint covariance is ``[[P_X, C], [C^T, P_Y]]``."""
    rms_rotation: float
    """RMS rotation residual (rad) of ``Y^-1 G_i X C_i``."""
    rms_translation: float
    """RMS translation residual (m, or the inputs' unit) of ``Y^-1 G_i X C_i``: the scatter of
    the target's origin as each sample places it."""
    noise_from_residuals: bool
    """True if no input covariances were given and the noise was estimated from residuals."""


_CLOSED_FORMS = {"park_martin": hand_eye_park_martin, "daniilidis": hand_eye_daniilidis}


def _pose_covariances(name: str, value: Any, count: int) -> np.ndarray:
    """N x 6 x 6 covariances; one 6x6 matrix stands for every sample."""
    array = np.asarray(value, dtype=float)
    if array.shape == (6, 6):
        array = np.broadcast_to(array, (count, 6, 6))
    return as_covariances(name, array, count, 6)


def _residual_covariances(
    hand_translations: np.ndarray,
    camera: RigidTransform,
    target: RigidTransform,
    residuals: np.ndarray,
    noise: tuple[np.ndarray, np.ndarray] | None,
) -> np.ndarray:
    """Covariances (N x 6 x 6) of the residuals ``Log(G_i X C_i Y^-1)`` (base frame).

    From the inputs, first order: ``G_i X C_i = Exp(g_i) Exp(Ad_{G_i X} c_i) G_i X C_i`` gives
    ``Sigma_G,i + Ad_{G_i X} Sigma_C,i Ad_{G_i X}^T``.

    Without them, from the residuals seen at the target, ``(a_i, b_i) = Ad_{Y^-1} r_i``
    (rotation, displacement of the target's origin, target axes), with the model of the usual
    sensors: a rotation error ``phi_c ~ N(0, v_c I)`` about the hand's origin, which moves the
    target by ``phi_c x l_i`` (``l_i``: hand origin -> target), a rotation error
    ``phi_t ~ N(0, v_t I)`` about the target (the eye's), and a displacement ``N(0, v_d I)``::

        a_i = phi_c + phi_t,   b_i = phi_c x l_i + d_i.

    Moments, chosen so that the small variance ``v_d`` is not the difference of two large
    sums (which, clamped at zero, made the weights over-confident): ``v_d`` from the
    displacement along ``l_i`` (which ``phi_c x l_i`` cannot produce), ``v_c`` from the
    displacement across ``l_i`` less ``2 v_d``, ``v_t`` from the rotations less ``v_c``; sums
    are divided by ``N - 2`` per dimension (6N residuals, 12 unknowns). A simpler model (one
    rotation and one displacement variance at the target) ignores the lever arm; at 0.5 deg of
    hand rotation noise its mean NEES was about 8 instead of 6 (the covariance about 30 %
    small).
    """
    if noise is not None:
        hand_covariances, eye_covariances = noise
        translation, rotation = camera.as_components()
        transport = adjoint(rotation.as_quat(), translation)
        return hand_covariances + transport @ eye_covariances @ np.swapaxes(transport, 1, 2)
    n = len(residuals)
    translation, rotation = target.as_components()
    to_base = adjoint(rotation.as_quat(), translation)
    at_target = residuals @ np.linalg.inv(to_base).T
    turn, shift = at_target[:, :3], at_target[:, 3:]
    lever = rotation.inv().apply(translation - hand_translations)
    lengths = np.linalg.norm(lever, axis=1)
    direction = lever / np.maximum(lengths, 1e-300)[:, None]
    along = np.sum(shift * direction, axis=1)
    across = shift - along[:, None] * direction
    dof = n - 2.0
    displacement = max(float(np.sum(np.square(along))) / dof, _VARIANCE_FLOOR)
    rotation_total = max(float(np.sum(np.square(turn))) / (3.0 * dof), _VARIANCE_FLOOR)
    lever_excess = float(np.sum(np.square(across))) * n / dof - 2.0 * n * displacement
    about_hand = min(
        max(lever_excess / (2.0 * float(np.sum(np.square(lengths)))), 0.0), rotation_total
    )
    about_target = max(rotation_total - about_hand, 1e-3 * rotation_total)
    mixing = np.broadcast_to(np.eye(6), (n, 6, 6)).copy()
    mixing[:, 3:, :3] = -skew(lever)
    local = mixing @ np.diag(np.repeat([about_hand, displacement], 3)) @ np.swapaxes(mixing, 1, 2)
    local[:, :3, :3] += about_target * np.eye(3)
    return to_base @ local @ to_base.T


def hand_eye_calibration(
    hand_rotations: np.ndarray,
    hand_translations: np.ndarray,
    eye_rotations: np.ndarray,
    eye_translations: np.ndarray,
    hand_covariances: np.ndarray | None = None,
    eye_covariances: np.ndarray | None = None,
    method: str = "park_martin",
) -> HandEyeSolution:
    """``X`` (eye in hand) and ``Y`` (target in base) with their joint covariance.

    Inputs as for :func:`hand_eye_park_martin` (N >= 3 simultaneous poses ``G_i`` of the hand in
    the base and ``C_i`` of the static target in the eye), plus optionally the poses' 6x6
    left-perturbation covariances (N x 6 x 6, or one 6x6 for all samples): give both or
    neither. ``method`` (``"park_martin"`` or ``"daniilidis"``) is the closed form over all
    motion pairs that starts the refinement. Park-Martin is the default: started from either,
    the refinement reaches the same estimate (to 1e-13 in the trials checked; at the
    Cramér-Rao bound, with a translation RMS 23-42 % below the better closed form in
    ``bench.calibration_bench``), and Park-Martin's closed form takes 3-9x less CPU at
    100-1,000 poses.

    Refinement (module docstring): Gauss-Newton on ``X <- Exp(dx) X``, ``Y <- Exp(dy) Y`` over
    the residuals ``r_i = Log(G_i X C_i Y^-1)``, Jacobian ``[Ad_{G_i}, -I]``, weights the
    inverse residual covariances (see :func:`_residual_covariances`: from the inputs, or
    estimated from the residuals when none are given), re-evaluated every iteration. The
    covariance is the inverse of the Gauss-Newton information ``sum J_i^T S_i^-1 J_i`` at the
    solution (first order; Barfoot & Furgale, IEEE T-RO 2014, for the SE(3) perturbations).

    Cost: the closed form is O(N^2) (all ``N (N - 1) / 2`` motion pairs), the refinement O(N)
    per iteration (see ``docs/performance.md`` for the measured times).
    """
    if method not in _CLOSED_FORMS:
        raise ValueError(f"method: must be one of {sorted(_CLOSED_FORMS)}, got {method!r}")
    if (hand_covariances is None) != (eye_covariances is None):
        raise ValueError("hand_covariances, eye_covariances: give both or neither")
    initial = _CLOSED_FORMS[method](
        hand_rotations, hand_translations, eye_rotations, eye_translations
    )
    hand_q = as_quaternions("hand_rotations", hand_rotations)
    hand = rigid(hand_q, np.asarray(hand_translations, dtype=float))
    eye = rigid(np.asarray(eye_rotations, dtype=float), np.asarray(eye_translations, dtype=float))
    n = len(hand_q)
    noise = None
    if hand_covariances is not None:
        noise = (
            _pose_covariances("hand_covariances", hand_covariances, n),
            _pose_covariances("eye_covariances", eye_covariances, n),
        )
    x = rigid(initial.rotation, initial.translation)
    samples = hand * x * eye
    y = RigidTransform.from_components(samples.translation.mean(axis=0), samples.rotation.mean())
    jacobian = np.concatenate(
        (adjoint(hand_q, hand.translation), np.broadcast_to(-np.eye(6), (n, 6, 6))), axis=2
    )
    for _ in range(_MAX_ITERATIONS):
        camera = hand * x
        residuals = (camera * eye * y.inv()).as_exp_coords()
        weights = np.linalg.inv(
            _residual_covariances(hand.translation, camera, y, residuals, noise)
        )
        weighted_jacobian = weights @ jacobian
        information = np.einsum("nji,njk->ik", jacobian, weighted_jacobian)
        step = -np.linalg.solve(information, np.einsum("nji,nj->i", weighted_jacobian, residuals))
        x = RigidTransform.from_exp_coords(step[:6]) * x
        y = RigidTransform.from_exp_coords(step[6:]) * y
        if np.abs(step).max() < _CONVERGED:
            break
    covariance = symmetric(np.linalg.inv(information))
    offsets, rotations = (y.inv() * hand * x * eye).as_components()
    return HandEyeSolution(
        to_estimate(x, covariance[:6, :6]),
        to_estimate(y, covariance[6:, 6:]),
        covariance[:6, 6:],
        float(np.sqrt(np.mean(np.square(rotations.magnitude())))),
        float(np.sqrt(np.mean(np.sum(np.square(offsets), axis=1)))),
        noise is None,
    )
