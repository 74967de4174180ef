import numpy as np
import pytest

from bench.synthetic import left_error, random_quaternion, rng_for, rotation_error, sample_poses
from ubitrack_agent.services.algorithms.estimate import PoseEstimate
from ubitrack_agent.services.algorithms.fusion import fuse_poses

COV = np.diag([1e-4, 2e-4, 1e-4, 1e-6, 1e-6, 4e-6])


def test_identical_estimates_fuse_to_themselves_with_halved_covariance():
    rng = rng_for("fusion-identical")
    q, t = random_quaternion(rng), rng.uniform(-1, 1, 3)
    fused = fuse_poses([q, q], [t, t], [COV, COV])
    assert rotation_error(fused.rotation, q) < 1e-12
    np.testing.assert_allclose(fused.translation, t, atol=1e-12)
    np.testing.assert_allclose(fused.covariance, COV / 2, rtol=1e-12)


def test_fused_mean_is_stationary_point_of_weighted_residuals():
    rng = rng_for("fusion-stationary")
    truth = PoseEstimate(random_quaternion(rng), np.array([0.5, 1.0, 2.0]))
    covs = np.stack((COV, 3 * COV, np.diag([1e-3] * 3 + [1e-7] * 3)))
    q, t = sample_poses(rng, truth, covs)
    fused = fuse_poses(q, t, covs)
    xi = np.array([left_error(PoseEstimate(qi, ti), fused) for qi, ti in zip(q, t, strict=True)])
    gradient = np.einsum("mij,mj->i", np.linalg.inv(covs), xi)
    assert np.linalg.norm(gradient) < 1e-6


def test_two_equal_trackers_improve_by_about_sqrt_two_and_covariance_is_consistent():
    rng = rng_for("fusion-monte-carlo")
    truth = PoseEstimate(random_quaternion(rng), np.array([0.5, 1.0, 2.0]))
    single, fused_errors = [], []
    for _ in range(300):
        q, t = sample_poses(rng, truth, [COV, COV])
        fused = fuse_poses(q, t, [COV, COV])
        single.append(left_error(PoseEstimate(q[0], t[0]), truth))
        fused_errors.append(left_error(fused, truth))
    ratio = np.sqrt(np.mean(np.square(single)) / np.mean(np.square(fused_errors)))
    assert 1.3 < ratio < 1.53
    spread = np.diag(np.cov(np.array(fused_errors).T)) / np.diag(fused.covariance)
    assert np.all((spread > 0.75) & (spread < 1.3)), spread


def test_complementary_anisotropic_trackers():
    good_x = np.diag([1e-6] * 3 + [1e-8, 1e-4, 1e-4])
    good_y = np.diag([1e-6] * 3 + [1e-4, 1e-8, 1e-4])
    fused = fuse_poses([[0, 0, 0, 1.0]] * 2, np.zeros((2, 3)), [good_x, good_y])
    assert fused.covariance[3, 3] < 1.01e-8 and fused.covariance[4, 4] < 1.01e-8


@pytest.mark.parametrize(
    ("q", "t", "covs", "message"),
    [
        (np.zeros((0, 4)), np.zeros((0, 3)), np.zeros((0, 6, 6)), "at least 1"),
        ([[0, 0, 0, 1.0]], [[0, 0, 0.0]], [-COV], "positive definite"),
        ([[0, 0, 0, 1.0]], [[0, 0, 0.0]], [COV, COV], "shape"),
        ([[0, 0, 0, 1.0]], [[0, 0, np.nan]], [COV], "NaN"),
    ],
)
def test_fusion_bad_input_raises_value_error(q, t, covs, message):
    with pytest.raises(ValueError, match=message):
        fuse_poses(q, t, covs)
