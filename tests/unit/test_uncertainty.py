"""Covariance propagation: Monte Carlo against the first-order adjoint formulas.

Protocol of field-notes section 9: sample xi ~ N(0, Sigma), perturb on the left
(T = Exp(xi) T_mean), push through the operation, take the sample covariance of
Log(T_out T_out_mean^-1), compare with the formula evaluated on the sample input covariance.
"""

import numpy as np
import pytest
from scipy.spatial.transform import RigidTransform, Rotation

from ubitrack_agent.core import decode, encode, se3, uncertainty
from ubitrack_agent.core.measurements import FULL, ErrorPose, Pose, Position3D
from ubitrack_agent.core.poses import (
    compose_poses,
    interpolate_pose,
    invert_pose,
    transform_position,
)

N_SAMPLES = 40_000


def random_covariance(rng, sigma_rot: float, sigma_t: float) -> np.ndarray:
    """Correlated anisotropic 6x6 covariance with the given overall scales."""
    scales = np.array([sigma_rot] * 3 + [sigma_t] * 3)
    a = rng.normal(size=(6, 6))
    corr = a @ a.T + 6 * np.eye(6)
    d = np.sqrt(np.diag(corr))
    corr = corr / np.outer(d, d)
    stretch = rng.uniform(0.5, 1.5, size=6)
    return corr * np.outer(scales * stretch, scales * stretch)


def sample_left(rng, mean: RigidTransform, cov: np.ndarray):
    xi = rng.multivariate_normal(np.zeros(6), cov, size=N_SAMPLES)
    return RigidTransform.from_exp_coords(xi) * mean, xi


def tangent_covariance(samples: RigidTransform, mean: RigidTransform) -> np.ndarray:
    xi = (samples * mean.inv()).as_exp_coords()
    return np.cov(xi, rowvar=False)


def relative_error(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def mean_transform(rng, lever_arm: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    direction = rng.normal(size=3)
    return Rotation.random(rng=rng).as_quat(), lever_arm * direction / np.linalg.norm(direction)


def to_scipy(q, t) -> RigidTransform:
    return RigidTransform.from_components(t, Rotation.from_quat(q))


@pytest.mark.parametrize("sigma_deg, sigma_mm", [(1.0, 1.0), (0.1, 0.1)])
def test_inversion_matches_monte_carlo(sigma_deg, sigma_mm):
    rng = np.random.default_rng(11)
    q, t = mean_transform(rng)
    cov = random_covariance(rng, np.radians(sigma_deg), sigma_mm / 1000)
    samples, xi = sample_left(rng, to_scipy(q, t), cov)
    qi, ti = se3.invert(q, t)
    sampled = tangent_covariance(samples.inv(), to_scipy(qi, ti))
    predicted = uncertainty.invert_covariance(q, t, np.cov(xi, rowvar=False))
    assert relative_error(predicted, sampled) < 1e-9  # exact, no linearisation


@pytest.mark.parametrize("sigma_deg, sigma_mm, tolerance", [(1.0, 1.0, 0.01), (5.0, 5.0, 0.03)])
def test_concatenation_matches_monte_carlo(sigma_deg, sigma_mm, tolerance):
    rng = np.random.default_rng(12)
    (q1, t1), (q2, t2) = mean_transform(rng), mean_transform(rng)
    cov1 = random_covariance(rng, np.radians(sigma_deg), sigma_mm / 1000)
    cov2 = random_covariance(rng, np.radians(sigma_deg), sigma_mm / 1000)
    s1, xi1 = sample_left(rng, to_scipy(q1, t1), cov1)
    s2, xi2 = sample_left(rng, to_scipy(q2, t2), cov2)
    sampled = tangent_covariance(s1 * s2, to_scipy(*se3.compose(q1, t1, q2, t2)))
    predicted = uncertainty.compose_covariance(
        q1, t1, np.cov(xi1, rowvar=False), np.cov(xi2, rowvar=False)
    )
    assert relative_error(predicted, sampled) < tolerance
    # Ignoring the adjoint (plain sum) is grossly wrong at a 1 m lever arm: the test can fail.
    assert relative_error(cov1 + cov2, sampled) > 0.3


def test_adjoint_moves_perturbation_through_transform():
    rng = np.random.default_rng(13)
    q, t = mean_transform(rng)
    xi = rng.normal(size=6) * 0.1
    transform = to_scipy(q, t)
    left = transform * RigidTransform.from_exp_coords(xi) * transform.inv()
    moved = RigidTransform.from_exp_coords(uncertainty.adjoint(q, t) @ xi)
    np.testing.assert_allclose(left.as_matrix(), moved.as_matrix(), atol=1e-12)


def test_batched_adjoint_and_compose():
    rng = np.random.default_rng(14)
    q = Rotation.random(4, rng=rng).as_quat()
    t = rng.normal(size=(4, 3))
    cov = np.broadcast_to(np.eye(6) * 1e-4, (4, 6, 6))
    out = uncertainty.compose_covariance(q, t, cov, cov)
    assert out.shape == (4, 6, 6)
    single = uncertainty.compose_covariance(q[2], t[2], cov[2], cov[2])  # the scalar path
    np.testing.assert_allclose(out[2], single, rtol=1e-12, atol=1e-18)  # round-off of 1e-4


def test_pose_level_operations_propagate_and_keep_plain_poses_plain():
    rng = np.random.default_rng(15)
    q, t = mean_transform(rng)
    cov = random_covariance(rng, np.radians(1.0), 0.001)
    exact = Pose(10, q, t)
    uncertain = ErrorPose(20, q, t, cov)
    assert type(compose_poses(exact, exact)) is Pose
    assert type(invert_pose(exact)) is Pose
    combined = compose_poses(exact, uncertain)
    assert isinstance(combined, ErrorPose) and combined.timestamp_ns == 20
    expected = uncertainty.compose_covariance(q, t, np.zeros((6, 6)), cov)
    np.testing.assert_allclose(combined.covariance, expected, atol=1e-18)
    inverse = invert_pose(uncertain)
    np.testing.assert_allclose(
        compose_poses(uncertain, inverse).translation, np.zeros(3), atol=1e-12
    )


def test_propagated_covariances_stay_symmetric_to_round_off_along_a_chain():
    """Results are not symmetrised (``poses._make``): along 200 compositions and inversions of
    badly scaled covariances their asymmetry stays at round-off and every one passes the
    ``FULL`` validation a subscriber's decoder applies."""
    rng = np.random.default_rng(16)
    pose = ErrorPose(1, *mean_transform(rng, 2.0), random_covariance(rng, 0.02, 0.005))
    for step in range(200):
        q, t = mean_transform(rng, 3.0)
        other = ErrorPose(1, q, t, random_covariance(rng, 10.0 ** -rng.uniform(1, 5), 1e-4))
        pose = compose_poses(other, pose) if step % 3 else invert_pose(pose)
        cov = pose.covariance
        assert np.abs(cov - cov.T).max() <= 1e-14 * np.abs(cov).max()
        decode(encode(pose), level=FULL)  # raises if not symmetric positive semi-definite


def test_transform_position_covariance_matches_monte_carlo():
    rng = np.random.default_rng(16)
    q, t = mean_transform(rng)
    cov_pose = random_covariance(rng, np.radians(1.0), 0.001)
    point = rng.normal(size=3)
    cov_point = np.diag([1e-6, 4e-6, 9e-6])
    result = transform_position(ErrorPose(0, q, t, cov_pose), Position3D(0, point, cov_point))
    samples, _ = sample_left(rng, to_scipy(q, t), cov_pose)
    noisy_points = point + rng.multivariate_normal(np.zeros(3), cov_point, size=N_SAMPLES)
    sampled = np.cov(samples.apply(noisy_points), rowvar=False)
    assert relative_error(result.covariance, sampled) < 0.03


def test_interpolate_pose_blends_and_refuses_to_extrapolate():
    from ubitrack_agent.core.errors import ExtrapolationError

    rng = np.random.default_rng(17)
    (q0, t0), (q1, t1) = mean_transform(rng), mean_transform(rng)
    a = ErrorPose(1_000, q0, t0, np.eye(6) * 1e-6)
    b = ErrorPose(2_000, q1, t1, np.eye(6) * 3e-6)
    mid = interpolate_pose(a, b, 1_250)
    assert mid.timestamp_ns == 1_250
    np.testing.assert_allclose(mid.translation, 0.75 * t0 + 0.25 * t1)
    np.testing.assert_allclose(mid.covariance, np.eye(6) * 1.5e-6)
    assert interpolate_pose(a, b, 1_000) == ErrorPose(
        1_000, *se3.interpolate(q0, t0, q1, t1, 0.0), np.eye(6) * 1e-6
    )
    with pytest.raises(ExtrapolationError):
        interpolate_pose(a, b, 2_001)


def test_isotropic_pose_covariance_puts_rotation_first():
    covariance = uncertainty.isotropic_pose_covariance(np.radians(0.05), 0.0003)
    np.testing.assert_allclose(
        np.diag(covariance), [np.radians(0.05) ** 2] * 3 + [0.0003**2] * 3, rtol=1e-15
    )
    assert np.count_nonzero(covariance - np.diag(np.diag(covariance))) == 0


@pytest.mark.parametrize("lever_arm", [0.0, 3.0])
def test_in_place_covariance_matches_monte_carlo(lever_arm):
    """Noise about the body's own origin (as an outside-in tracker's), seen on the left."""
    rng = np.random.default_rng(18)
    q, t = mean_transform(rng, lever_arm)
    cov = uncertainty.isotropic_pose_covariance(np.radians(0.5), 0.0005)
    phi, rho = np.split(rng.multivariate_normal(np.zeros(6), cov, size=N_SAMPLES), 2, axis=1)
    samples = RigidTransform.from_components(
        t + rho, Rotation.from_rotvec(phi) * Rotation.from_quat(q)
    )
    sampled = tangent_covariance(samples, to_scipy(q, t))
    predicted = uncertainty.in_place_covariance(t, np.cov(np.hstack([phi, rho]), rowvar=False))
    assert relative_error(predicted, sampled) < 0.01
    if lever_arm:  # at a 3 m lever arm the left covariance is not the in-place one
        assert relative_error(cov, sampled) > 0.5
