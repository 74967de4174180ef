"""Input buffers: interpolation, static inputs, tolerance window, bounded history."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ubitrack_agent.core import ErrorPose, Pose, Position2D, Position3D, Rotation3D, quaternions
from ubitrack_agent.core.timeline import MAX_FUTURE_NS, SampleBuffer, ahead_of_clock, interpolate

MS = 1_000_000


def pose(t_ms: int, x: float, yaw_deg: float = 0.0) -> Pose:
    return Pose(t_ms * MS, Rotation.from_euler("z", yaw_deg, degrees=True).as_quat(), [x, 0, 0])


def test_dynamic_input_interpolates_pose_between_samples():
    buffer = SampleBuffer(static=False)
    buffer.add(pose(0, 0.0, 0.0))
    buffer.add(pose(10, 1.0, 20.0))
    value = buffer.value_at(5 * MS, tolerance_ns=0)
    assert value.timestamp_ns == 5 * MS
    np.testing.assert_allclose(value.translation, [0.5, 0, 0])
    assert np.degrees(quaternions.angle(value.rotation)) == pytest.approx(10.0)


def test_exact_timestamp_returns_the_sample_itself():
    buffer = SampleBuffer(static=False)
    sample = pose(3, 1.0)
    buffer.add(sample)
    assert buffer.value_at(3 * MS, 0) is sample


def test_outside_samples_uses_nearest_only_within_tolerance():
    buffer = SampleBuffer(static=False)
    buffer.add(pose(0, 0.0))
    buffer.add(pose(10, 1.0))
    late = buffer.value_at(15 * MS, tolerance_ns=6 * MS)
    assert late.timestamp_ns == 15 * MS
    np.testing.assert_allclose(late.translation, [1.0, 0, 0])
    assert buffer.value_at(17 * MS, tolerance_ns=6 * MS) is None
    early = SampleBuffer(static=False)
    early.add(pose(100, 0.0))
    assert early.value_at(90 * MS, tolerance_ns=5 * MS) is None


def test_static_input_answers_latest_value_at_any_time():
    buffer = SampleBuffer(static=True)
    buffer.add(pose(0, 0.0))
    buffer.add(pose(5, 2.0))
    value = buffer.value_at(10_000 * MS, tolerance_ns=0)
    np.testing.assert_allclose(value.translation, [2.0, 0, 0])
    assert value.timestamp_ns == 10_000 * MS
    assert len(buffer) == 1


def test_empty_buffer_has_no_value():
    assert SampleBuffer(static=False).value_at(0, 10**9) is None


def test_history_is_bounded_and_out_of_order_samples_are_sorted():
    buffer = SampleBuffer(static=False, history=4)
    for t in (0, 30, 10, 20, 40, 50):
        buffer.add(pose(t, t / 10))
    assert len(buffer) == 4
    np.testing.assert_allclose(buffer.value_at(25 * MS, 0).translation, [2.5, 0, 0])
    buffer.add(pose(5, 99.0))  # older than everything kept: ignored
    assert buffer.value_at(5 * MS, 0) is None


def test_position_rotation_and_covariance_interpolation():
    a = Position3D(0, [0, 0, 0], np.eye(3))
    b = Position3D(10, [10, 0, 0], 3 * np.eye(3))
    mid = interpolate(a, b, 5)
    np.testing.assert_allclose(mid.position, [5, 0, 0])
    np.testing.assert_allclose(mid.covariance, 2 * np.eye(3))
    r0 = Rotation3D(0, [0, 0, 0, 1])
    r1 = Rotation3D(10, Rotation.from_euler("x", 90, degrees=True).as_quat())
    assert np.degrees(quaternions.angle(interpolate(r0, r1, 5).rotation)) == pytest.approx(45)
    e0 = ErrorPose(0, [0, 0, 0, 1], [0, 0, 0], np.eye(6))
    e1 = ErrorPose(10, [0, 0, 0, 1], [1, 0, 0], 3 * np.eye(6))
    np.testing.assert_allclose(interpolate(e0, e1, 5).covariance, 2 * np.eye(6))


def test_types_without_interpolation_fall_back_to_nearest_within_tolerance():
    buffer = SampleBuffer(static=False)
    buffer.add(Position2D(0, [0, 0]))
    buffer.add(Position2D(10 * MS, [10, 0]))
    assert interpolate(buffer.latest(), buffer.latest(), 10 * MS) is None
    value = buffer.value_at(8 * MS, tolerance_ns=3 * MS)
    np.testing.assert_allclose(value.position, [10, 0])
    assert buffer.value_at(5 * MS, tolerance_ns=3 * MS) is None


def test_strict_lookup_raises_typed_errors():
    from ubitrack_agent.core import ExtrapolationError, NoDataError

    buffer = SampleBuffer(static=False)
    with pytest.raises(NoDataError):
        buffer.lookup(0)
    buffer.add(pose(0, 0.0))
    buffer.add(pose(10, 1.0))
    np.testing.assert_allclose(buffer.lookup(4 * MS).translation, [0.4, 0, 0])
    with pytest.raises(ExtrapolationError):
        buffer.lookup(11 * MS)
    late = SampleBuffer(static=False)
    late.add(pose(5, 0.0))
    with pytest.raises(ExtrapolationError):
        late.lookup(4 * MS)
    static = SampleBuffer(static=True)
    static.add(pose(0, 3.0))
    assert static.lookup(10**12).timestamp_ns == 10**12
    images = SampleBuffer(static=False)
    images.add(Position2D(0, [0, 0]))
    images.add(Position2D(10, [10, 0]))
    np.testing.assert_allclose(images.lookup(7).position, [10, 0])


def test_a_sample_beyond_a_full_buffers_horizon_is_refused():
    buffer = SampleBuffer(static=False, history=3)
    assert all(buffer.add(Pose(t, [0, 0, 0, 1], [0, 0, 0])) for t in (10, 20, 30))
    assert not buffer.add(Pose(5, [0, 0, 0, 1], [0, 0, 0]))
    assert buffer.add(Pose(15, [0, 0, 0, 1], [0, 0, 0]))  # within the horizon: inserted
    assert [buffer.value_at(t, 0).timestamp_ns for t in (15, 20, 30)] == [15, 20, 30]


def test_ahead_of_clock_bound():
    now = 1_700_000_000 * 10**9
    assert not ahead_of_clock(now + MAX_FUTURE_NS, now)
    assert ahead_of_clock(now + MAX_FUTURE_NS + 1, now)
    assert not ahead_of_clock(0, now)  # the past is accepted: replayed recordings


def test_a_shifted_buffer_holds_the_same_values_later_and_leaves_out_what_leaves_the_range():
    buffer = SampleBuffer(static=False, history=3)
    for t_ms, x in ((10, 1.0), (20, 2.0), (30, 3.0)):
        buffer.add(pose(t_ms, x))
    moved = buffer.shifted(-15_000_000)  # 15 ms earlier: the first sample leaves the range
    assert len(moved) == 2 and moved.newest_time() == 15_000_000
    assert moved.lookup(10_000_000).translation[0] == pytest.approx(2.5)
    assert buffer.newest_time() == 30_000_000  # the original is unchanged
    assert moved.add(pose(1, 0.0)) and len(moved) == 3  # room for its whole history
    assert not moved.add(pose(0, 0.0))  # full again: its horizon holds
