import numpy as np
import pytest

from bench.synthetic import random_quaternion, rng_for, rotation_error
from ubitrack_agent.services.algorithms.auxiliary import (
    compose_projection,
    decompose_projection,
    split_pose,
)
from ubitrack_agent.services.algorithms.estimate import PoseEstimate, perturb_left, rigid

K = np.array([[810.0, 1.5, 322.0], [0.0, 790.0, 236.0], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize("scale", [1.0, 2.5, -0.01])
def test_projection_round_trip_for_any_homogeneous_scale(scale):
    rng = rng_for("aux-projection")
    pose = PoseEstimate(random_quaternion(rng), rng.uniform(-1, 1, 3))
    camera_matrix, recovered = decompose_projection(scale * compose_projection(K, pose))
    np.testing.assert_allclose(camera_matrix, K, atol=1e-9)
    assert rotation_error(recovered.rotation, pose.rotation) < 1e-12
    np.testing.assert_allclose(recovered.translation, pose.translation, atol=1e-12)


def test_singular_projection_raises():
    with pytest.raises(ValueError, match="singular"):
        decompose_projection(np.hstack((np.ones((3, 3)), np.ones((3, 1)))))
    with pytest.raises(ValueError, match="shape"):
        decompose_projection(np.eye(3))


def test_split_pose_translation_covariance_matches_monte_carlo():
    rng = rng_for("aux-split")
    q, t = random_quaternion(rng), np.array([0.5, -1.0, 2.0])
    a = rng.normal(size=(6, 6)) * 1e-3
    cov = a @ a.T + 1e-7 * np.eye(6)
    q_out, t_out, cov_rot, cov_t = split_pose(q, t, cov)
    np.testing.assert_array_equal(t_out, t)
    np.testing.assert_array_equal(q_out, q)
    np.testing.assert_array_equal(cov_rot, cov[:3, :3])
    samples = perturb_left(rng.multivariate_normal(np.zeros(6), cov, 20000), rigid(q, t))
    sample_cov = np.cov(samples.translation.T)
    np.testing.assert_allclose(cov_t, sample_cov, rtol=0.05, atol=1e-3 * np.abs(cov_t).max())


def test_split_pose_without_covariance_and_bad_input():
    assert split_pose([0, 0, 0, 1], [1, 2, 3])[2:] == (None, None)
    with pytest.raises(ValueError, match="unit quaternion"):
        split_pose([0, 0, 0, 2], [1, 2, 3])
    with pytest.raises(ValueError, match="positive definite"):
        split_pose([0, 0, 0, 1], [1, 2, 3], -np.eye(6))
