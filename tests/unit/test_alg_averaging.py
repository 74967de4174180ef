import numpy as np
import pytest

from bench.synthetic import left_error, random_quaternion, rng_for, rotation_error, sample_poses
from ubitrack_agent.services.algorithms.averaging import average_poses, average_positions
from ubitrack_agent.services.algorithms.estimate import PoseEstimate

COV = np.diag([1e-4, 1e-4, 4e-4, 1e-6, 4e-6, 1e-6])


def test_identical_poses_average_to_themselves():
    rng = rng_for("avg-identical")
    q, t = random_quaternion(rng), rng.uniform(-1, 1, 3)
    mean = average_poses([q] * 5, [t] * 5)
    assert rotation_error(mean.rotation, q) < 1e-12
    np.testing.assert_allclose(mean.translation, t, atol=1e-12)
    np.testing.assert_allclose(mean.covariance, 0.0, atol=1e-24)


def test_single_pose_has_no_covariance():
    assert average_poses([[0, 0, 0, 1.0]], [[1, 2, 3.0]]).covariance is None
    assert average_positions([[1, 2, 3.0]])[1] is None


def test_covariance_of_the_mean_matches_monte_carlo():
    rng = rng_for("avg-monte-carlo")
    truth = PoseEstimate(random_quaternion(rng), np.array([0.3, -0.2, 1.5]))
    errors, predicted = [], []
    for _ in range(200):
        mean = average_poses(*sample_poses(rng, truth, [COV] * 20))
        errors.append(left_error(mean, truth))
        predicted.append(mean.covariance)
    ratio = np.diag(np.cov(np.array(errors).T)) / np.diag(np.mean(predicted, axis=0))
    assert np.all((ratio > 0.75) & (ratio < 1.3)), ratio
    np.testing.assert_allclose(np.diag(np.mean(predicted, axis=0)), np.diag(COV) / 20, rtol=0.1)


def test_positions():
    rng = rng_for("avg-positions")
    points = rng.normal([1, 2, 3], 0.01, (400, 3))
    mean, cov = average_positions(points)
    np.testing.assert_allclose(mean, [1, 2, 3], atol=3e-3)
    np.testing.assert_allclose(np.diag(cov), 1e-4 / 400, rtol=0.25)


@pytest.mark.parametrize(
    ("q", "t", "message"),
    [
        (np.zeros((0, 4)), np.zeros((0, 3)), "at least 1"),
        ([[0, 0, 0, 1.0]], [[0, 0, np.nan]], "NaN"),
        ([[0, 0, 0, 1.0]] * 2, [[0, 0, 0.0]], "same number"),
        ([[0, 0, 1, 1.0]], [[0, 0, 0.0]], "unit"),
    ],
)
def test_bad_input_raises_value_error(q, t, message):
    with pytest.raises(ValueError, match=message):
        average_poses(q, t)
    if message == "NaN":
        with pytest.raises(ValueError, match=message):
            average_positions(t)
