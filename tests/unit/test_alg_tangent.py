import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bench.synthetic import random_quaternion, rng_for
from ubitrack_agent.services.algorithms.estimate import left_residuals, perturb_left, rigid
from ubitrack_agent.services.algorithms.tangent import SPACES

# Rotation sizes (per axis) from exactly zero through round-off-sized to about 2 rad.
SCALES = [0.0, 1e-12, 1e-7, 1e-3, 0.3, 0.6]


def _poses(rng, scale, n=40):
    reference = np.concatenate((random_quaternion(rng), rng.normal(size=3)))
    rotations = Rotation.from_rotvec(rng.normal(0, scale, (n, 3))) * Rotation.from_quat(
        reference[:4]
    )
    values = np.hstack((rotations.as_quat(), reference[4:] + rng.normal(0, 0.5, (n, 3))))
    return values, reference


@pytest.mark.parametrize("scale", SCALES)
def test_pose_log_and_exp_match_scipy(scale):
    rng = rng_for(f"tangent-pose-{scale}")
    space = SPACES["pose"]
    values, reference = _poses(rng, scale)
    ref = rigid(reference[:4], reference[4:])
    expected = left_residuals(rigid(values[:, :4], values[:, 4:]), ref)
    np.testing.assert_allclose(space.logs(values, reference), expected, rtol=0, atol=1e-13)
    xi = np.hstack((rng.normal(0, scale, (40, 3)), rng.normal(0, 0.5, (40, 3))))
    translations, rotations = perturb_left(xi, ref).as_components()
    ours = np.array([space.exp(x, reference) for x in xi])
    np.testing.assert_allclose(ours[:, 4:], translations, rtol=0, atol=1e-13)
    np.testing.assert_allclose(np.abs(np.sum(ours[:, :4] * rotations.as_quat(), axis=1)), 1.0)
    np.testing.assert_allclose(space.logs(ours, reference), xi, rtol=0, atol=1e-13)


def test_pose_log_near_half_turn_and_sign_of_quaternion():
    rng = rng_for("tangent-half-turn")
    space = SPACES["pose"]
    reference = np.concatenate((random_quaternion(rng), [0.1, 0.2, 0.3]))
    axis = rng.normal(size=3)
    rotation = Rotation.from_rotvec(axis / np.linalg.norm(axis) * (np.pi - 1e-6))
    q = (rotation * Rotation.from_quat(reference[:4])).as_quat()
    for sign in (1.0, -1.0):
        value = np.concatenate((sign * q, [0.5, -0.5, 1.0]))
        expected = left_residuals(rigid(q, value[4:]), rigid(reference[:4], reference[4:]))[0]
        np.testing.assert_allclose(space.log(value, reference), expected, atol=1e-9)


@pytest.mark.parametrize("scale", SCALES)
def test_rotation_log_and_exp_match_scipy(scale):
    rng = rng_for(f"tangent-rotation-{scale}")
    space = SPACES["rotation"]
    reference = random_quaternion(rng)
    phi = rng.normal(0, scale, (40, 3))
    values = (Rotation.from_rotvec(phi) * Rotation.from_quat(reference)).as_quat()
    np.testing.assert_allclose(space.logs(values, reference), phi, rtol=0, atol=1e-13)
    ours = np.array([space.exp(p, reference) for p in phi])
    np.testing.assert_allclose(np.abs(np.sum(ours * values, axis=1)), 1.0)


def test_position_space_is_plain_difference():
    space = SPACES["position"]
    assert space.log((1.0, 2.0, 3.0), (0.5, 0.5, 0.5)) == (0.5, 1.5, 2.5)
    assert space.exp((0.5, 1.5, 2.5), (0.5, 0.5, 0.5)) == (1.0, 2.0, 3.0)
    np.testing.assert_array_equal(space.translation_jacobian((0.0, 0.0, 0.0)), np.eye(3))
    assert SPACES["rotation"].translation_jacobian((0.0, 0.0, 0.0, 1.0)) is None


def test_translation_jacobian_is_the_first_order_change_of_the_translation():
    rng = rng_for("tangent-jacobian")
    space = SPACES["pose"]
    reference = np.concatenate((random_quaternion(rng), rng.normal(size=3)))
    xi = rng.normal(0, 1e-6, 6)
    moved = np.array(space.exp(xi, reference))[4:] - reference[4:]
    np.testing.assert_allclose(
        moved, space.translation_jacobian(reference) @ xi, rtol=0, atol=1e-11
    )


@pytest.mark.parametrize("kind", ["pose", "rotation"])
def test_adjoint_gives_the_second_order_change_of_reference(kind):
    # Log(Exp(y) Exp(-x)) = y - x + ad(x) y / 2 + third order: what the static estimator
    # relies on when it moves its linearisation point.
    rng = rng_for(f"tangent-adjoint-{kind}")
    space = SPACES[kind]
    reference = random_quaternion(rng)
    if kind == "pose":
        reference = np.concatenate((reference, rng.normal(size=3)))
    x = rng.normal(0, 0.01, space.dim)
    for y in rng.normal(0, 0.02, (20, space.dim)):
        value = space.exp(y, reference)
        exact = np.array(space.log(value, space.exp(x, reference)))
        second = y - x + 0.5 * space.adjoint(x) @ y
        assert np.abs(exact - second).max() < 0.05 * np.abs(exact - (y - x)).max()
        assert np.abs(exact - second).max() < 1e-5
    np.testing.assert_allclose(space.adjoint(x) @ x, 0.0, atol=1e-18)  # [x, x] = 0


def test_positions_are_flat():
    assert SPACES["position"].adjoint((1.0, 2.0, 3.0)) is None
