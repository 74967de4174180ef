import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bench.synthetic import left_error, random_quaternion, rng_for, rotation_error
from ubitrack_agent.services.algorithms.absolute_orientation import absolute_orientation
from ubitrack_agent.services.algorithms.estimate import PoseEstimate


def _scene(name: str, n: int = 10):
    rng = rng_for(name)
    q = random_quaternion(rng)
    t = rng.uniform(-1, 1, 3)
    b = rng.uniform(-0.25, 0.25, (n, 3))
    a = Rotation.from_quat(q).apply(b) + t
    return rng, q, t, a, b


def test_noise_free_recovers_ground_truth():
    _, q, t, a, b = _scene("ao-exact")
    est = absolute_orientation(a, b)
    assert rotation_error(est.rotation, q) < 1e-9
    np.testing.assert_allclose(est.translation, t, atol=1e-9)


def test_three_points_suffice_and_weights_are_accepted():
    _, q, t, a, b = _scene("ao-three", n=3)
    est = absolute_orientation(a, b, weights=[1.0, 2.0, 3.0])
    assert rotation_error(est.rotation, q) < 1e-9
    np.testing.assert_allclose(est.translation, t, atol=1e-9)


def test_covariance_matches_monte_carlo_spread():
    rng, q, t, a, b = _scene("ao-monte-carlo")
    sigma = 1e-3
    predicted = absolute_orientation(a, b, sigma=sigma).covariance
    errors = []
    for _ in range(300):
        est = absolute_orientation(a + rng.normal(0, sigma, a.shape), b)
        errors.append(left_error(est, PoseEstimate(q, t)))
    sample = np.cov(np.array(errors).T)
    ratio = np.diag(sample) / np.diag(predicted)
    assert np.all((ratio > 0.7) & (ratio < 1.4)), ratio


def test_estimated_sigma_is_close_to_true_noise():
    rng, _, _, a, b = _scene("ao-sigma", n=200)
    noisy = absolute_orientation(a + rng.normal(0, 1e-3, a.shape), b)
    exact = absolute_orientation(a, b, sigma=1e-3)
    ratio = np.diag(noisy.covariance) / np.diag(exact.covariance)
    assert np.all((ratio > 0.8) & (ratio < 1.25)), ratio


@pytest.mark.parametrize(
    ("a", "b", "message"),
    [
        (np.zeros((2, 3)), np.zeros((2, 3)), "at least 3"),
        (np.zeros((4, 2)), np.zeros((4, 3)), "shape"),
        (np.full((4, 3), np.nan), np.zeros((4, 3)), "NaN"),
        (np.ones((4, 3)), np.ones((5, 3)), "same number"),
        (np.outer(np.arange(5.0), [1, 2, 3]), np.outer(np.arange(5.0), [3, 2, 1]), "collinear"),
    ],
)
def test_bad_input_raises_value_error(a, b, message):
    with pytest.raises(ValueError, match=message):
        absolute_orientation(a, b)


def test_non_positive_weights_and_sigma_raise():
    _, _, _, a, b = _scene("ao-bad-weights")
    with pytest.raises(ValueError, match="weights"):
        absolute_orientation(a, b, weights=-np.ones(len(a)))
    with pytest.raises(ValueError, match="sigma"):
        absolute_orientation(a, b, sigma=0.0)
