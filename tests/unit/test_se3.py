"""Quaternion and SE(3) maths against scipy's independent implementation."""

import numpy as np
import pytest
from scipy.spatial.transform import RigidTransform, Rotation, Slerp

from ubitrack_agent.core import quaternions, se3

RNG = np.random.default_rng(7)


def random_transforms(n: int, rng: np.random.Generator = RNG) -> tuple[np.ndarray, np.ndarray]:
    return Rotation.random(n, rng=rng).as_quat(), rng.normal(scale=2.0, size=(n, 3))


def as_scipy(q: np.ndarray, t: np.ndarray) -> RigidTransform:
    return RigidTransform.from_components(t, Rotation.from_quat(q))


def assert_same_rotation(q_a: np.ndarray, q_b: np.ndarray) -> None:
    # q and -q are the same rotation
    np.testing.assert_allclose(np.abs(np.sum(q_a * q_b, axis=-1)), 1.0, atol=1e-12)


def test_product_and_matrix_match_scipy():
    a, b = Rotation.random(100, rng=RNG), Rotation.random(100, rng=RNG)
    assert_same_rotation(quaternions.multiply(a.as_quat(), b.as_quat()), (a * b).as_quat())
    np.testing.assert_allclose(quaternions.to_matrix(a.as_quat()), a.as_matrix(), atol=1e-14)
    v = RNG.normal(size=(100, 3))
    np.testing.assert_allclose(quaternions.rotate(a.as_quat(), v), a.apply(v), atol=1e-13)


def test_single_quaternion_shapes():
    q = Rotation.random(rng=RNG).as_quat()
    assert quaternions.multiply(q, q).shape == (4,)
    assert quaternions.rotate(q, np.ones(3)).shape == (3,)
    assert quaternions.to_matrix(q).shape == (3, 3)
    # one rotation broadcast over many points
    assert quaternions.rotate(q, np.ones((5, 3))).shape == (5, 3)


def vector_of(quaternion: np.ndarray) -> np.ndarray:
    return Rotation.from_quat(quaternion).as_rotvec()


def test_rotation_vector_maps_match_scipy():
    rng = np.random.default_rng(5)
    vectors = np.concatenate(
        (
            rng.normal(size=(50, 3)),
            1e-9 * rng.normal(size=(5, 3)),
            3.1 * np.eye(3),
            np.zeros((1, 3)),
        )
    )
    expected = Rotation.from_rotvec(vectors).as_quat()
    q = quaternions.from_rotvec(vectors)
    assert np.allclose(np.abs(np.sum(q * expected, axis=1)), 1.0, atol=1e-12)
    assert np.allclose(quaternions.to_rotvec(expected), Rotation.from_quat(expected).as_rotvec())
    assert np.allclose(quaternions.to_rotvec(-expected), Rotation.from_quat(expected).as_rotvec())
    for vector, quaternion in zip(vectors, expected, strict=True):  # one at a time: scalar path
        assert abs(abs(quaternions.from_rotvec(vector) @ quaternion) - 1.0) < 1e-12
        np.testing.assert_allclose(quaternions.to_rotvec(quaternion), vector_of(quaternion))
        np.testing.assert_allclose(quaternions.to_rotvec(-quaternion), vector_of(quaternion))


def test_conjugate_inverts():
    q = Rotation.random(20, rng=RNG).as_quat()
    assert_same_rotation(quaternions.multiply(q, quaternions.conjugate(q)), quaternions.IDENTITY)


def test_angle_is_geodesic_and_exact_for_tiny_angles():
    rot = Rotation.random(50, rng=RNG)
    np.testing.assert_allclose(quaternions.angle(rot.as_quat()), rot.magnitude(), atol=1e-12)
    tiny = Rotation.from_rotvec([1e-12, 0.0, 0.0]).as_quat()
    assert quaternions.angle(tiny) == pytest.approx(1e-12, rel=1e-9)


@pytest.mark.parametrize("s", [0.0, 0.25, 0.5, 0.9, 1.0])
def test_slerp_matches_scipy(s):
    q0, q1 = Rotation.random(2, rng=RNG).as_quat()
    expected = Slerp([0.0, 1.0], Rotation.from_quat([q0, q1]))([s]).as_quat()[0]
    assert_same_rotation(quaternions.slerp(q0, q1, s), expected)


def test_slerp_takes_short_arc_and_handles_identical_inputs():
    q = Rotation.random(rng=RNG).as_quat()
    assert_same_rotation(quaternions.slerp(q, -q, 0.3), q)
    assert_same_rotation(quaternions.slerp(q, q, 0.7), q)


def test_compose_invert_transform_match_scipy():
    q1, t1 = random_transforms(30)
    q2, t2 = random_transforms(30)
    q, t = se3.compose(q1, t1, q2, t2)
    expected = as_scipy(q1, t1) * as_scipy(q2, t2)
    np.testing.assert_allclose(se3.to_matrix(q, t), expected.as_matrix(), atol=1e-12)
    qi, ti = se3.invert(q1, t1)
    np.testing.assert_allclose(
        se3.to_matrix(qi, ti), as_scipy(q1, t1).inv().as_matrix(), atol=1e-12
    )
    points = RNG.normal(size=(30, 3))
    np.testing.assert_allclose(
        se3.transform_points(q1, t1, points), as_scipy(q1, t1).apply(points), atol=1e-12
    )


def test_matrix_round_trip():
    q, t = random_transforms(10)
    q2, t2 = se3.from_matrix(se3.to_matrix(q, t))
    assert_same_rotation(q, q2)
    np.testing.assert_allclose(t, t2, atol=1e-14)


def test_interpolate_endpoints_and_midpoint():
    (q0, q1), (t0, t1) = random_transforms(2)
    for s, (q_want, t_want) in ((0.0, (q0, t0)), (1.0, (q1, t1))):
        q, t = se3.interpolate(q0, t0, q1, t1, s)
        assert_same_rotation(q, q_want)
        np.testing.assert_allclose(t, t_want, atol=1e-14)
    q, t = se3.interpolate(q0, t0, q1, t1, 0.5)
    np.testing.assert_allclose(t, (t0 + t1) / 2)
    half = quaternions.angle(quaternions.multiply(quaternions.conjugate(q0), q))
    whole = quaternions.angle(quaternions.multiply(quaternions.conjugate(q0), q1))
    assert half == pytest.approx(whole / 2, rel=1e-9)


def test_batched_interpolation():
    q0, t0 = random_transforms(8)
    q1, t1 = random_transforms(8)
    s = np.linspace(0.0, 1.0, 8)
    q, t = se3.interpolate(q0, t0, q1, t1, s)
    assert q.shape == (8, 4) and t.shape == (8, 3)
    np.testing.assert_allclose(t[-1], t1[-1])
