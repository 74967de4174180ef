import numpy as np
import pytest
from scipy.stats import chi2

from bench.synthetic import (
    eye_poses,
    hand_eye_camera_scene,
    hand_eye_scene,
    left_error,
    noisy_hand_eye_scene,
    perturb_poses,
    random_quaternion,
    rng_for,
    rotation_error,
)
from ubitrack_agent.core import quaternions, se3
from ubitrack_agent.core.uncertainty import adjoint
from ubitrack_agent.services.algorithms.averaging import average_poses
from ubitrack_agent.services.algorithms.estimate import PoseEstimate
from ubitrack_agent.services.algorithms.hand_eye import (
    _unit_orthogonal_combination,
    hand_eye_calibration,
    hand_eye_daniilidis,
    hand_eye_park_martin,
)

SOLVERS = [hand_eye_park_martin, hand_eye_daniilidis]


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("all_pairs", [True, False])
def test_noise_free_recovers_ground_truth(solver, all_pairs):
    truth, poses = hand_eye_scene(rng_for("he-exact"), 6)
    est = solver(*poses, all_pairs=all_pairs)
    assert rotation_error(est.rotation, truth.rotation) < 1e-9
    np.testing.assert_allclose(est.translation, truth.translation, atol=1e-9)


@pytest.mark.parametrize("solver", SOLVERS)
def test_three_poses_suffice(solver):
    truth, poses = hand_eye_scene(rng_for("he-three"), 3)
    est = solver(*poses)
    np.testing.assert_allclose(est.translation, truth.translation, atol=1e-9)


@pytest.mark.parametrize("solver", SOLVERS)
def test_noisy_poses_give_errors_of_the_noise_order(solver):
    rng = rng_for("he-noisy")
    rot_errors, trans_errors = [], []
    for _ in range(20):
        truth, (qg, tg, qc, tc) = hand_eye_scene(rng, 10)
        qg, tg = perturb_poses(rng, qg, tg, np.radians(0.1), 1e-3)
        qc, tc = perturb_poses(rng, qc, tc, np.radians(0.1), 1e-3)
        est = solver(qg, tg, qc, tc)
        rot_errors.append(rotation_error(est.rotation, truth.rotation))
        trans_errors.append(np.linalg.norm(est.translation - truth.translation))
    assert np.degrees(np.sqrt(np.mean(np.square(rot_errors)))) < 0.3
    assert np.sqrt(np.mean(np.square(trans_errors))) < 5e-3


@pytest.mark.parametrize("solver", SOLVERS)
def test_rotations_about_one_axis_are_degenerate(solver):
    rng = rng_for("he-degenerate")
    truth, _ = hand_eye_scene(rng, 3)
    angles = np.linspace(0.1, 1.0, 5)
    hand_q = np.column_stack((np.zeros((5, 2)), np.sin(angles / 2), np.cos(angles / 2)))
    hand_t = rng.uniform(-0.5, 0.5, (5, 3))
    target = (np.array([0, 0, 0, 1.0]), np.array([0.1, 0.2, 0.3]))
    with pytest.raises(ValueError, match="degenerate"):
        solver(hand_q, hand_t, *eye_poses(truth, target, hand_q, hand_t))


IDENTITY4 = np.tile([0, 0, 0, 1.0], (4, 1))


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((IDENTITY4[:2], np.zeros((2, 3)), IDENTITY4[:2], np.zeros((2, 3))), "at least 3"),
        ((IDENTITY4 * 2, np.zeros((4, 3)), IDENTITY4, np.zeros((4, 3))), "unit"),
        ((IDENTITY4, np.zeros((4, 3)), IDENTITY4[:3], np.zeros((3, 3))), "same number"),
        ((IDENTITY4, np.full((4, 3), np.nan), IDENTITY4, np.zeros((4, 3))), "NaN"),
    ],
)
def test_bad_input_raises_value_error(args, message):
    with pytest.raises(ValueError, match=message):
        hand_eye_park_martin(*args)


@pytest.mark.parametrize("seed", range(12))
def test_daniilidis_keeps_the_real_solution_when_a_null_vector_is_almost_purely_dual(seed):
    # The exact null space is span{(q, q'), (0, q)}; with noise the SVD may return a basis
    # vector close to (0, q), and Daniilidis' "largest value" rule then picked the spurious
    # root (a translation of kilometres in one noisy trial of 30 camera poses).
    rng = rng_for(f"he-dual-basis-{seed}")
    truth = PoseEstimate(random_quaternion(rng), rng.uniform(-0.1, 0.1, 3))
    q = truth.rotation
    q_dual = 0.5 * quaternions.multiply(np.append(truth.translation, 0.0), q)
    first = np.concatenate((1e-2 * rng.normal(size=4), q))
    second = np.concatenate((q, q_dual)) + 1e-2 * rng.normal(size=8)
    first /= np.linalg.norm(first)
    second -= (second @ first) * first
    second /= np.linalg.norm(second)
    real, dual = _unit_orthogonal_combination(first[:4], first[4:], second[:4], second[4:])
    translation = 2.0 * quaternions.multiply(dual, quaternions.conjugate(real))[:3]
    assert rotation_error(real, q) < 0.1
    np.testing.assert_allclose(translation, truth.translation, atol=0.1)


# --- joint refinement with covariances ------------------------------------------------------


def nees(error, covariance):
    return float(error @ np.linalg.solve(covariance, error))


def mean_nees_interval(dof, trials, confidence=0.99):
    """Two-sided interval of the mean of ``trials`` chi-square(dof) values."""
    return chi2.ppf([(1 - confidence) / 2, (1 + confidence) / 2], dof * trials) / trials


@pytest.mark.parametrize("method", ["park_martin", "daniilidis"])
@pytest.mark.parametrize("with_covariances", [True, False])
def test_calibration_recovers_ground_truth_from_exact_poses(method, with_covariances):
    truth, target, poses = hand_eye_camera_scene(rng_for("he-joint-exact"), 6)
    covariances = (np.eye(6) * 1e-6, np.eye(6) * 1e-6) if with_covariances else (None, None)
    solution = hand_eye_calibration(*poses, *covariances, method=method)
    for estimate, expected in ((solution.eye_in_hand, truth), (solution.target_in_base, target)):
        assert rotation_error(estimate.rotation, expected.rotation) < 1e-9
        np.testing.assert_allclose(estimate.translation, expected.translation, atol=1e-9)
    assert solution.rms_rotation < 1e-9
    assert solution.rms_translation < 1e-9
    assert solution.noise_from_residuals is not with_covariances


@pytest.mark.parametrize("level", ["low", "high"])
def test_covariances_of_x_and_target_are_consistent_and_the_averaged_one_is_not(level):
    """Monte Carlo NEES: 200 seeded trials of 10 poses at realistic noise. The mean NEES of X
    and of Y (6 dof each) lies in the 99 % interval of the mean of chi-square values, and so
    does that of ``e_Y - Ad_{G_1} e_X``, whose covariance needs the cross terms (without them
    its mean NEES is about 4). The covariance of the plain average of ``G_i X C_i``, which
    ignores the error of X that every sample shares, fails it."""
    rng = rng_for(f"he-nees-{level}")
    trials = 200
    values = {"x": [], "y": [], "derived": [], "averaged": []}
    for _ in range(trials):
        truth, target, poses, covariances = noisy_hand_eye_scene(rng, 10, level)
        solution = hand_eye_calibration(*poses, *covariances)
        x, y, cross = solution.eye_in_hand, solution.target_in_base, solution.cross_covariance
        error_x, error_y = left_error(x, truth), left_error(y, target)
        qg, tg, qc, tc = poses
        transport = adjoint(qg[0], tg[0])
        derived = y.covariance + transport @ x.covariance @ transport.T
        derived -= transport @ cross + (transport @ cross).T
        values["x"].append(nees(error_x, x.covariance))
        values["y"].append(nees(error_y, y.covariance))
        values["derived"].append(nees(error_y - transport @ error_x, derived))
        samples = se3.compose(*se3.compose(qg, tg, x.rotation, x.translation), qc, tc)
        averaged = average_poses(*samples)
        values["averaged"].append(nees(left_error(averaged, target), averaged.covariance))
    low, high = mean_nees_interval(6, trials)
    for name in ("x", "y", "derived"):
        assert low < np.mean(values[name]) < high, name
    assert np.mean(values["averaged"]) > 2 * high


@pytest.mark.parametrize("level", ["low", "high"])
def test_covariances_estimated_from_residuals_are_consistent(level):
    """Without input covariances (noise estimated from the residuals), 30 poses; at the high
    level the hand's 0.5 deg rotation noise reaches the target through a lever arm of about
    0.6 m, which a model without the lever arm misses (mean NEES about 8)."""
    rng = rng_for(f"he-nees-residuals-{level}")
    trials = 150
    values_x, values_y = [], []
    for _ in range(trials):
        truth, target, poses, _ = noisy_hand_eye_scene(rng, 30, level)
        solution = hand_eye_calibration(*poses)
        x, y = solution.eye_in_hand, solution.target_in_base
        values_x.append(nees(left_error(x, truth), x.covariance))
        values_y.append(nees(left_error(y, target), y.covariance))
    low, high = mean_nees_interval(6, trials)
    assert low < np.mean(values_x) < high
    assert low < np.mean(values_y) < high


def test_one_covariance_stands_for_every_sample():
    _, _, poses, _ = noisy_hand_eye_scene(rng_for("he-one-cov"), 8, "low")
    hand_one, eye_one = np.diag([1e-5, 1e-5, 1e-5, 1e-6, 1e-6, 1e-6]), np.eye(6) * 4e-6
    single = hand_eye_calibration(*poses, hand_one, eye_one)
    stacked = hand_eye_calibration(
        *poses, np.tile(hand_one, (8, 1, 1)), np.tile(eye_one, (8, 1, 1))
    )
    np.testing.assert_allclose(single.eye_in_hand.covariance, stacked.eye_in_hand.covariance)


def test_calibration_rejects_rotations_about_one_axis():
    rng = rng_for("he-joint-degenerate")
    truth, _ = hand_eye_scene(rng, 3)
    angles = np.linspace(0.1, 1.0, 5)
    hand_q = np.column_stack((np.zeros((5, 2)), np.sin(angles / 2), np.cos(angles / 2)))
    hand_t = rng.uniform(-0.5, 0.5, (5, 3))
    target = (np.array([0, 0, 0, 1.0]), np.array([0.1, 0.2, 0.3]))
    for method in ("park_martin", "daniilidis"):
        with pytest.raises(ValueError, match="degenerate"):
            hand_eye_calibration(
                hand_q, hand_t, *eye_poses(truth, target, hand_q, hand_t), method=method
            )


@pytest.mark.parametrize(
    ("covariances", "method", "message"),
    [
        ((np.eye(6), None), "park_martin", "both or neither"),
        ((np.eye(6), np.eye(5)), "park_martin", "eye_covariances: shape"),
        ((np.eye(6), -np.eye(6)), "park_martin", "positive definite"),
        ((None, None), "tsai", "method"),
    ],
)
def test_calibration_bad_input_raises_value_error(covariances, method, message):
    _, _, poses = hand_eye_camera_scene(rng_for("he-joint-bad"), 5)
    with pytest.raises(ValueError, match=message):
        hand_eye_calibration(*poses, *covariances, method=method)
