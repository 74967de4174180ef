import numpy as np
import pytest

from bench.synthetic import (
    eye_poses,
    hand_eye_scene,
    perturb_poses,
    random_quaternion,
    rng_for,
    rotation_error,
)
from services.algorithms.estimate import PoseEstimate
from services.algorithms.hand_eye import (
    _unit_orthogonal_combination,
    hand_eye_daniilidis,
    hand_eye_park_martin,
)
from ubitrack_agent.core import quaternions

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
