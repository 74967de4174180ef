import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from bench.synthetic import (
    body_noise_covariances,
    perturb_with_covariances,
    pivot_scene,
    rng_for,
)
from ubitrack_agent.core.uncertainty import skew
from ubitrack_agent.services.algorithms.tip_calibration import tip_calibration

SIGMA_ROT = np.radians(0.2)
SIGMA_T = 0.25e-3
"""A realistic optical tracker: 0.2 deg about the marker's origin, 0.25 mm per axis."""


def noisy_pivoting(rng, n_poses):
    tip, pivot, (q, t) = pivot_scene(rng, n_poses)
    covariances = body_noise_covariances(t, SIGMA_ROT, SIGMA_T)
    return tip, pivot, (q, t), perturb_with_covariances(rng, q, t, covariances), covariances


def nees(error, covariance):
    return float(error @ np.linalg.solve(covariance, error))


def mean_nees_interval(dof, trials, confidence=0.99):
    return chi2.ppf([(1 - confidence) / 2, (1 + confidence) / 2], dof * trials) / trials


def cramer_rao_bound(q, pivot, covariances):
    """Inverse Fisher information of (p_m, p_w) at the true poses, written independently of the
    module: residual ``R_i p_m + t_i - p_w`` with the tip displaced by ``phi x p_w + rho``."""
    rotations = Rotation.from_quat(q).as_matrix()
    lever = np.concatenate((-skew(pivot), np.eye(3)), axis=1)
    information = np.zeros((6, 6))
    for rotation, covariance in zip(rotations, covariances, strict=True):
        design = np.hstack((rotation, -np.eye(3)))
        information += design.T @ np.linalg.solve(lever @ covariance @ lever.T, design)
    return np.linalg.inv(information)


@pytest.mark.parametrize("with_covariances", [True, False])
def test_exact_poses_give_the_tip_and_the_pivot(with_covariances):
    tip, pivot, (q, t) = pivot_scene(rng_for("tip-exact"), 5)
    covariances = body_noise_covariances(t, SIGMA_ROT, SIGMA_T) if with_covariances else None
    solution = tip_calibration(q, t, covariances)
    np.testing.assert_allclose(solution.tip_in_marker, tip, atol=1e-10)
    np.testing.assert_allclose(solution.pivot_in_tracker, pivot, atol=1e-10)
    assert solution.rms_residual < 1e-10
    assert solution.noise_from_residuals is not with_covariances


def test_a_tip_at_the_marker_origin_is_found():
    rng = rng_for("tip-origin")
    q = Rotation.random(6, rng=rng).as_quat()
    pivot = np.array([0.1, -0.2, 0.3])
    solution = tip_calibration(q, np.tile(pivot, (6, 1)))
    np.testing.assert_allclose(solution.tip_in_marker, 0.0, atol=1e-10)
    np.testing.assert_allclose(solution.pivot_in_tracker, pivot, atol=1e-10)


def test_covariances_are_consistent_and_reach_the_cramer_rao_bound():
    """300 seeded trials of 20 poses: mean NEES of p_m and of p_w (3 dof each) inside the 99 %
    interval, and the mean squared errors within 15 % of the bound's trace (their Monte Carlo
    spread is about 5 %)."""
    rng = rng_for("tip-nees")
    trials = 300
    nees_tip, nees_pivot, squared, bound = [], [], [], []
    for _ in range(trials):
        tip, pivot, (q_true, _), (q, t), covariances = noisy_pivoting(rng, 20)
        solution = tip_calibration(q, t, covariances)
        error_tip, error_pivot = solution.tip_in_marker - tip, solution.pivot_in_tracker - pivot
        nees_tip.append(nees(error_tip, solution.tip_covariance))
        nees_pivot.append(nees(error_pivot, solution.pivot_covariance))
        squared.append((error_tip @ error_tip, error_pivot @ error_pivot))
        crlb = cramer_rao_bound(q_true, pivot, covariances)
        bound.append((np.trace(crlb[:3, :3]), np.trace(crlb[3:, 3:])))
    low, high = mean_nees_interval(3, trials)
    assert low < np.mean(nees_tip) < high
    assert low < np.mean(nees_pivot) < high
    np.testing.assert_allclose(np.mean(squared, axis=0) / np.mean(bound, axis=0), 1.0, atol=0.15)


def test_noise_estimated_from_residuals_gives_consistent_covariances():
    rng = rng_for("tip-nees-residuals")
    trials = 200
    nees_tip, nees_pivot = [], []
    for _ in range(trials):
        tip, pivot, _, (q, t), _ = noisy_pivoting(rng, 30)
        solution = tip_calibration(q, t)
        nees_tip.append(nees(solution.tip_in_marker - tip, solution.tip_covariance))
        nees_pivot.append(nees(solution.pivot_in_tracker - pivot, solution.pivot_covariance))
    low, high = mean_nees_interval(3, trials)
    assert low < np.mean(nees_tip) < high
    assert low < np.mean(nees_pivot) < high


def test_one_covariance_stands_for_every_sample():
    _, _, _, (q, t), _ = noisy_pivoting(rng_for("tip-one-cov"), 8)
    one = np.diag([1e-5, 1e-5, 1e-5, 1e-7, 1e-7, 1e-7])
    single = tip_calibration(q, t, one)
    stacked = tip_calibration(q, t, np.tile(one, (8, 1, 1)))
    np.testing.assert_allclose(single.tip_covariance, stacked.tip_covariance)
    np.testing.assert_allclose(single.cross_covariance, stacked.cross_covariance)


@pytest.mark.parametrize("noise_deg", [0.0, 0.2])
def test_rotations_about_one_axis_are_rejected(noise_deg):
    rng = rng_for("tip-one-axis")
    angles = np.linspace(-0.6, 0.6, 12)
    spin = Rotation.from_rotvec(np.outer(angles, [0.0, 0.0, 1.0]))
    noise = Rotation.from_rotvec(rng.normal(0.0, np.radians(noise_deg), (12, 3)))
    tip, pivot = np.array([0.0, 0.15, 0.0]), np.array([0.1, 0.2, 0.3])
    rotations = noise * spin
    with pytest.raises(ValueError, match=r"degenerate motion.*one axis"):
        tip_calibration(rotations.as_quat(), pivot - rotations.apply(tip))


@pytest.mark.parametrize(
    ("q", "t", "covariances", "message"),
    [
        (np.tile([0, 0, 0, 1.0], (2, 1)), np.zeros((2, 3)), None, "at least 3"),
        (np.tile([0, 0, 0, 2.0], (3, 1)), np.zeros((3, 3)), None, "unit"),
        (np.tile([0, 0, 0, 1.0], (3, 1)), np.zeros((4, 3)), None, "same number"),
        (np.tile([0, 0, 0, 1.0], (3, 1)), np.zeros((3, 3)), np.eye(3), "covariances: shape"),
        (np.tile([0, 0, 0, 1.0], (3, 1)), np.zeros((3, 3)), -np.eye(6), "positive definite"),
    ],
)
def test_bad_input_raises_value_error(q, t, covariances, message):
    with pytest.raises(ValueError, match=message):
        tip_calibration(q, t, covariances)
