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

Why by hand: ``cv2.calibrateHandEye`` is not exposed in the OpenCV 5.0.0 Python wheels
(opencv/opencv#29565, fixed for 5.1). The motions need at least two rotations about
non-parallel axes; otherwise ``ValueError``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from services.algorithms._checks import as_points, as_quaternions, same_count
from services.algorithms.estimate import PoseEstimate
from ubitrack_agent.core import quaternions, se3

_PARALLEL_AXES = 1e-6


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
