"""Synthetic ground truth and error metrics shared by the accuracy benchmark and the unit tests.

Protocol of ``field-notes.md`` section 2: fixed seeds
``numpy.random.default_rng([20240601, crc32(name)])``, camera f = 800 px, c = (320, 240),
640 x 480, no distortion; rotation error is the geodesic angle of ``R_est R_gt^T``.
"""

from __future__ import annotations

import zlib
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2
from scipy.stats import t as student

from ubitrack_agent.core import quaternions, se3
from ubitrack_agent.core.uncertainty import skew
from ubitrack_agent.services.algorithms.auxiliary import compose_projection
from ubitrack_agent.services.algorithms.dlt import homogeneous
from ubitrack_agent.services.algorithms.estimate import (
    PoseEstimate,
    left_residuals,
    perturb_left,
    rigid,
)
from ubitrack_agent.services.algorithms.estimate import nees as estimate_nees

SEED = 20240601
CAMERA_MATRIX = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]])


def rng_for(name: str) -> np.random.Generator:
    """The experiment's fixed random generator."""
    return np.random.default_rng([SEED, zlib.crc32(name.encode())])


def random_quaternion(rng: np.random.Generator, size: int | None = None) -> np.ndarray:
    """Uniformly distributed unit quaternions (x, y, z, w)."""
    return Rotation.random(size, rng=rng).as_quat(canonical=True)


def rotation_error(q_est: np.ndarray, q_true: np.ndarray) -> np.ndarray:
    """Geodesic angle (radians) between rotations, ``angle(R_est R_true^T)``."""
    return quaternions.angle(quaternions.multiply(q_est, quaternions.conjugate(q_true)))


def left_error(estimate: PoseEstimate, truth: PoseEstimate) -> np.ndarray:
    """``xi`` (6,) with ``T_est = Exp(xi) T_true``: the error in the covariance's coordinates."""
    return left_residuals(
        rigid(estimate.rotation, estimate.translation), rigid(truth.rotation, truth.translation)
    )[0]


THREE_SIGMA_NEES = float(chi2.ppf(0.9973, 6))
"""NEES of a 6D error "beyond 3 sigma": the chi-square quantile of a 3-sigma probability
(20.06 for 6 degrees of freedom)."""


def nees(estimate: Any, truth: Any) -> float | None:
    """:func:`ubitrack_agent.services.algorithms.estimate.nees` of anything with a rotation, a
    translation and perhaps a covariance (a ``PoseEstimate``, a received ``Pose``/``ErrorPose``)
    against the truth."""
    return estimate_nees(
        PoseEstimate(
            estimate.rotation, estimate.translation, getattr(estimate, "covariance", None)
        ),
        PoseEstimate(truth.rotation, truth.translation),
    )


def nees_over_batches(batch_means: list[float | None], dimension: int = 6) -> dict | None:
    """The mean of independent batches' mean NEES (runs, or the seconds after separate
    events) and its 95 % t interval from their spread; ``consistent`` when ``dimension``, the
    expectation of an honest covariance's NEES, lies inside.

    Samples of one batch are not independent (a filter's errors are correlated over its time
    constant, and a session's samples share its static errors), so the mean of ``n`` of them is
    not chi-square(``dimension`` n) / n; batches are (the method of batch means: Law and Kelton,
    *Simulation Modeling and Analysis*, chapter 9; the NEES over Monte Carlo runs: Bar-Shalom,
    Li, Kirubarajan, *Estimation with Applications to Tracking and Navigation*, 2001, section
    5.4). ``None`` for fewer than two batches."""
    values = np.array([v for v in batch_means if v is not None], dtype=float)
    if len(values) < 2:
        return None
    half = student.ppf(0.975, len(values) - 1) * values.std(ddof=1) / np.sqrt(len(values))
    low, high = float(values.mean() - half), float(values.mean() + half)
    return {
        "mean": float(values.mean()),
        "interval_95": [low, high],
        "consistent": bool(low <= dimension <= high),
        "batch_means": [round(float(v), 3) for v in values],
    }


def sample_poses(
    rng: np.random.Generator, truth: PoseEstimate, covariances: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """One pose ``Exp(xi_i) T_true`` per covariance (M x 6 x 6): quaternions M x 4, t M x 3."""
    xi = np.array([rng.multivariate_normal(np.zeros(6), cov) for cov in covariances])
    translations, rotations = perturb_left(
        xi, rigid(truth.rotation, truth.translation)
    ).as_components()
    return rotations.as_quat(), translations


def project(points_camera: np.ndarray, camera_matrix: np.ndarray = CAMERA_MATRIX) -> np.ndarray:
    """Pinhole projection of points given in the camera frame (N x 3) to pixels (N x 2)."""
    homogeneous = points_camera @ camera_matrix.T
    return homogeneous[:, :2] / homogeneous[:, 2:]


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pose (q, t) of the world in a camera at ``eye`` looking at ``target`` (OpenCV axes)."""
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    rotation = np.stack((x, y, z))  # rows: camera axes in world; maps world to camera
    return Rotation.from_matrix(rotation).as_quat(), -rotation @ eye


def camera_ring(
    n_views: int, radius: float = 2.0, height: float = 1.0, arc: float = 2 * np.pi
) -> np.ndarray:
    """Projections (V x 3 x 4) of V cameras on a horizontal ring of ``radius`` at ``height``,
    ``arc / V`` apart, all looking at the origin (z up)."""
    angles = np.arange(n_views) * arc / n_views
    eyes = np.column_stack(
        (radius * np.cos(angles), radius * np.sin(angles), np.full(n_views, height))
    )
    poses = [PoseEstimate(*look_at(eye, np.zeros(3), np.array([0, 0, 1.0]))) for eye in eyes]
    return np.array([compose_projection(CAMERA_MATRIX, pose) for pose in poses])


def observe_points(projections: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Pixels (V x N x 2) of points (N x 3) through projections (V x 3 x 4)."""
    image = np.einsum("vij,nj->vni", projections, homogeneous(points))
    return image[..., :2] / image[..., 2:]


def hand_eye_scene(
    rng: np.random.Generator, n_poses: int
) -> tuple[PoseEstimate, tuple[np.ndarray, ...]]:
    """Ground truth ``X`` (eye in hand) and N noise-free (q_hand, t_hand, q_eye, t_eye).

    Hand poses: uniformly random rotations, positions in a 1 m cube; the target is static in
    the base; ``C_i = X^-1 G_i^-1 W`` (target in eye).
    """
    truth = PoseEstimate(random_quaternion(rng), rng.uniform(-0.1, 0.1, 3))
    target_q, target_t = random_quaternion(rng), rng.uniform(-0.5, 0.5, 3)
    hand_q, hand_t = random_quaternion(rng, n_poses), rng.uniform(-0.5, 0.5, (n_poses, 3))
    return truth, (hand_q, hand_t, *eye_poses(truth, (target_q, target_t), hand_q, hand_t))


def eye_poses(
    truth: PoseEstimate,
    target: tuple[np.ndarray, np.ndarray],
    hand_q: np.ndarray,
    hand_t: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Poses of a static ``target`` (in the base) in the eye, ``C_i = X^-1 G_i^-1 W``."""
    return se3.compose(
        *se3.invert(truth.rotation, truth.translation),
        *se3.compose(*se3.invert(hand_q, hand_t), *target),
    )


def perturb_poses(
    rng: np.random.Generator, q: np.ndarray, t: np.ndarray, sigma_rot: float, sigma_t: float
) -> tuple[np.ndarray, np.ndarray]:
    """Poses with Gaussian rotation-vector noise ``sigma_rot`` (rad) and translation noise
    ``sigma_t`` per axis."""
    noise = Rotation.from_rotvec(rng.normal(0, sigma_rot, (len(q), 3)))
    return (noise * Rotation.from_quat(q)).as_quat(), t + rng.normal(0, sigma_t, t.shape)


def body_noise_covariances(
    translations: np.ndarray, sigma_rot: float, sigma_t: np.ndarray | float
) -> np.ndarray:
    """Left-perturbation covariances (N x 6 x 6) of poses whose noise is a rotation of
    ``sigma_rot`` (rad, isotropic) about the body's own origin and a displacement of that
    origin with standard deviations ``sigma_t`` (m, scalar or per axis of the parent frame).

    ``Exp(xi) T`` moves the origin by ``phi x t + rho``, so ``rho = delta - phi x t`` and
    ``Sigma_xi = M diag(sigma_rot^2 I, diag(sigma_t^2)) M^T`` with ``M = [[I, 0], [[t]x, I]]``.
    """
    translations = np.atleast_2d(translations)
    mixing = np.broadcast_to(np.eye(6), (len(translations), 6, 6)).copy()
    mixing[:, 3:, :3] = skew(translations)
    body = np.diag(
        np.concatenate((np.full(3, sigma_rot**2), np.square(np.broadcast_to(sigma_t, 3))))
    )
    return mixing @ body @ np.swapaxes(mixing, 1, 2)


def perturb_with_covariances(
    rng: np.random.Generator, q: np.ndarray, t: np.ndarray, covariances: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Poses ``Exp(xi_i) T_i`` with ``xi_i ~ N(0, covariances[i])``: the estimators' model."""
    xi = np.einsum("nij,nj->ni", np.linalg.cholesky(covariances), rng.normal(size=(len(q), 6)))
    translations, rotations = perturb_left(xi, rigid(q, t)).as_components()
    return rotations.as_quat(), translations


def _looking_along(direction: np.ndarray, roll: float) -> np.ndarray:
    """Rotation (camera axes in the parent) whose z axis is ``direction``, rolled by ``roll``."""
    z = direction / np.linalg.norm(direction)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    frame = np.column_stack((x, np.cross(z, x), z))
    return Rotation.from_rotvec(roll * z).as_matrix() @ frame


def hand_eye_camera_scene(
    rng: np.random.Generator,
    n_poses: int,
    cone_deg: float = 40.0,
    distance: tuple[float, float] = (0.4, 0.8),
) -> tuple[PoseEstimate, PoseEstimate, tuple[np.ndarray, ...]]:
    """A camera on a hand looking at a static target, as in a real hand-eye calibration.

    Ground truth ``X`` (eye in hand: random rotation, offset within 0.1 m) and ``W`` (target in
    the base: random rotation, within a 1 m cube), and N noise-free (q_hand, t_hand, q_eye,
    t_eye). The camera sits ``distance`` m from the target, inside a cone of ``cone_deg``
    around the target's z axis, looks at the target's origin and is rolled uniformly about its
    optical axis; ``G_i = P_i X^-1`` for the camera pose ``P_i`` and ``C_i = P_i^-1 W``.
    """
    truth = PoseEstimate(random_quaternion(rng), rng.uniform(-0.1, 0.1, 3))
    target = PoseEstimate(random_quaternion(rng), rng.uniform(-0.5, 0.5, 3))
    polar = np.arccos(rng.uniform(np.cos(np.radians(cone_deg)), 1.0, n_poses))
    azimuth = rng.uniform(0.0, 2 * np.pi, n_poses)
    local = np.column_stack(
        (np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar))
    )
    directions = quaternions.rotate(target.rotation, local)
    camera_t = target.translation + rng.uniform(*distance, (n_poses, 1)) * directions
    camera_q = np.array(
        [
            Rotation.from_matrix(_looking_along(-d, roll)).as_quat()
            for d, roll in zip(directions, rng.uniform(-np.pi, np.pi, n_poses), strict=True)
        ]
    )
    hand = se3.compose(camera_q, camera_t, *se3.invert(truth.rotation, truth.translation))
    eye = se3.compose(*se3.invert(camera_q, camera_t), target.rotation, target.translation)
    return truth, target, (*hand, *eye)


def pivot_scene(
    rng: np.random.Generator, n_poses: int, cone_deg: float = 30.0, tip_length: float = 0.15
) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """A pointer pivoting on a fixed point: ground truth tip in the marker ``p_m`` (about
    ``tip_length`` m from the marker's origin, random direction), pivot in the tracker ``p_w``
    (within 0.5 m of the origin) and N noise-free marker poses (q, t) in the tracker.

    The pointer axis (tip -> marker) stays inside a cone of ``cone_deg`` around the tracker's
    z axis and the pointer is turned uniformly about its own axis, as a user pivots a pointer.
    """
    axis = rng.normal(size=3)
    tip = tip_length * axis / np.linalg.norm(axis) + rng.uniform(-0.01, 0.01, 3)
    pivot = rng.uniform(-0.5, 0.5, 3)
    polar = np.arccos(rng.uniform(np.cos(np.radians(cone_deg)), 1.0, n_poses))
    azimuth = rng.uniform(0.0, 2 * np.pi, n_poses)
    up = np.column_stack(
        (np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar))
    )
    rotations = []
    for direction, spin in zip(up, rng.uniform(-np.pi, np.pi, n_poses), strict=True):
        # marker rotation: the marker's -tip direction is mapped onto ``direction``, spun about it
        align, _ = Rotation.align_vectors(direction[None], -tip[None] / np.linalg.norm(tip))
        rotations.append((Rotation.from_rotvec(spin * direction) * align).as_quat())
    q = np.array(rotations)
    return tip, pivot, (q, pivot - quaternions.rotate(q, tip))


HAND_EYE_POSE_NOISE = {
    "low": ((np.radians(0.1), 1e-3), (np.radians(0.2), np.array([0.5e-3, 0.5e-3, 1e-3]))),
    "high": ((np.radians(0.5), 1e-3), (np.radians(1.0), np.array([1e-3, 1e-3, 2e-3]))),
}
"""Realistic hand-eye noise per pose, ``(hand, eye)``, each ``(sigma_rot, sigma_t)`` for
:func:`body_noise_covariances`: rotation (rad) about the body's origin and displacement (m) of
the origin; the eye's depth (its z axis) is the least accurate."""


def noisy_hand_eye_scene(
    rng: np.random.Generator, n_poses: int, level: str
) -> tuple[PoseEstimate, PoseEstimate, tuple[np.ndarray, ...], tuple[np.ndarray, np.ndarray]]:
    """:func:`hand_eye_camera_scene` with noise ``HAND_EYE_POSE_NOISE[level]`` drawn from the
    returned covariances: (X, target, (q_hand, t_hand, q_eye, t_eye), (hand_cov, eye_cov))."""
    truth, target, (qg, tg, qc, tc) = hand_eye_camera_scene(rng, n_poses)
    hand_noise, eye_noise = HAND_EYE_POSE_NOISE[level]
    hand_cov = body_noise_covariances(tg, *hand_noise)
    eye_cov = body_noise_covariances(tc, *eye_noise)
    qg, tg = perturb_with_covariances(rng, qg, tg, hand_cov)
    qc, tc = perturb_with_covariances(rng, qc, tc, eye_cov)
    return truth, target, (qg, tg, qc, tc), (hand_cov, eye_cov)
