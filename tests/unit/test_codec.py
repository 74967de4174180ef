"""Wire codec: exact round trips and clean rejection, property-tested with hypothesis."""

import contextlib

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ubitrack_agent.core import (
    CameraIntrinsics,
    ErrorPose,
    Measurement,
    MeasurementError,
    Pose,
    Position2D,
    Position3D,
    PositionList2D,
    PositionList3D,
    Projection,
    Rotation3D,
    decode,
    encode,
)
from ubitrack_agent.core.measurements import MAX_TIMESTAMP_NS, OPENCV_DISTORTION_LENGTHS

finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)
timestamps = st.integers(min_value=0, max_value=MAX_TIMESTAMP_NS)


def vectors(n: int):
    return st.lists(finite, min_size=n, max_size=n).map(np.array)


@st.composite
def quaternions(draw):
    v = draw(vectors(4))
    norm = np.linalg.norm(v)
    if norm < 1e-3:
        v, norm = np.array([0.0, 0.0, 0.0, 1.0]), 1.0
    return v / norm


@st.composite
def covariances(draw, n: int):
    a = draw(st.lists(st.floats(-1.0, 1.0), min_size=n * n, max_size=n * n).map(np.array))
    a = a.reshape(n, n) * draw(st.floats(1e-6, 1e2))
    return a @ a.T


def point_lists(dim: int):
    return st.integers(0, 20).flatmap(
        lambda n: st.lists(finite, min_size=n * dim, max_size=n * dim).map(
            lambda v: np.array(v).reshape(n, dim)
        )
    )


@st.composite
def intrinsics(draw):
    fx, fy = draw(st.floats(1.0, 1e4)), draw(st.floats(1.0, 1e4))
    matrix = [[fx, draw(finite), draw(finite)], [0.0, fy, draw(finite)], [0.0, 0.0, 1.0]]
    dist = draw(st.sampled_from(OPENCV_DISTORTION_LENGTHS).flatmap(vectors))
    size = draw(st.none() | st.tuples(st.integers(1, 8192), st.integers(1, 8192)))
    return CameraIntrinsics(draw(timestamps), matrix, dist, size)


@st.composite
def projections(draw):
    block = draw(covariances(3)) + np.eye(3)  # positive definite, hence regular
    return Projection(draw(timestamps), np.hstack((block, draw(vectors(3))[:, None])))


measurements = st.one_of(
    st.builds(Pose, timestamps, quaternions(), vectors(3)),
    st.builds(ErrorPose, timestamps, quaternions(), vectors(3), covariances(6)),
    st.builds(Position3D, timestamps, vectors(3), st.none() | covariances(3)),
    st.builds(Position2D, timestamps, vectors(2), st.none() | covariances(2)),
    st.builds(Rotation3D, timestamps, quaternions()),
    st.builds(PositionList3D, timestamps, point_lists(3)),
    st.builds(PositionList2D, timestamps, point_lists(2)),
    projections(),
    intrinsics(),
)


@given(measurements)
def test_round_trip_is_exact(value: Measurement):
    decoded = decode(encode(value))
    assert type(decoded) is type(value)
    assert decoded == value


@given(st.binary(max_size=400))
def test_random_bytes_are_rejected_cleanly(data: bytes):
    with contextlib.suppress(MeasurementError):
        decode(data)


@settings(max_examples=300)
@given(measurements, st.data())
def test_mutated_messages_decode_validly_or_are_rejected_cleanly(value, data):
    raw = bytearray(encode(value))
    for _ in range(data.draw(st.integers(1, 4))):
        position = data.draw(st.integers(0, len(raw) - 1))
        raw[position] = data.draw(st.integers(0, 255))
    if data.draw(st.booleans()):
        raw = raw[: data.draw(st.integers(0, len(raw)))]
    try:
        decoded = decode(bytes(raw))
    except MeasurementError:
        return
    # Whatever survived the mutation is still a fully valid measurement.
    assert decode(encode(decoded)) == decoded


POSE = encode(Pose(5, [0.0, 0.0, 0.0, 1.0], [1.0, 2.0, 3.0]))


def mutate(**changes) -> bytes:
    message = msgpack.unpackb(POSE)
    for key, value in changes.items():
        if value is None:
            del message[key]
        else:
            message[key] = value
    return msgpack.packb(message)


@pytest.mark.parametrize(
    "data, fragment",
    [
        (b"", "not valid msgpack"),
        (msgpack.packb([1, 2]), "expected a map"),
        (msgpack.packb({1: 2}), "not valid msgpack"),
        (msgpack.packb({"x": 2}), "message.v"),
        (mutate(v=2), "message.v: unsupported wire version"),
        (mutate(v=True), "message.v"),
        (mutate(type="Teleport"), "message.type: unknown measurement type"),
        (mutate(type=None), "message.type"),
        (mutate(t=None), "Pose.timestamp_ns: missing"),
        (mutate(t=-5), "Pose.timestamp_ns: out of range"),
        (mutate(t="now"), "Pose.timestamp_ns: must be an integer"),
        (mutate(rotation=None), "Pose.rotation: missing"),
        (mutate(rotation=[0, 0, 0, 1]), "Pose.rotation: expected float64 bytes"),
        (mutate(rotation=b"\x00" * 31), "Pose.rotation: 31 bytes"),
        (mutate(rotation=np.zeros(3).tobytes()), "Pose.rotation: 3 values do not fit"),
        (mutate(rotation=np.array([0, 0, 0, 2.0]).tobytes()), "unit quaternion"),
        (mutate(translation=np.array([0, np.nan, 0]).tobytes()), "Pose.translation: contains NaN"),
        (mutate(covariance=np.eye(6).tobytes()), "Pose: unknown keys ['covariance']"),
        (mutate(**{"../../etc": 1}), "unknown keys"),
        (b"\xc1", "not valid msgpack"),
        (msgpack.packb({"v": 1, "type": "Pose", "t": 1}) + b"extra", "not valid msgpack"),
    ],
)
def test_specific_defects_are_named(data, fragment):
    with pytest.raises(MeasurementError) as info:
        decode(data)
    assert fragment in str(info.value)


def test_expected_type_is_enforced():
    assert isinstance(decode(POSE, expected=(Pose, ErrorPose)), Pose)
    with pytest.raises(MeasurementError, match="expected Position3D, got Pose"):
        decode(POSE, expected=Position3D)


def test_non_bytes_and_oversized_input_rejected():
    with pytest.raises(MeasurementError, match="expected bytes"):
        decode("text")
    with pytest.raises(MeasurementError, match="exceeds"):
        decode(bytes(33 * 1024 * 1024))


def test_image_size_wire_form():
    value = CameraIntrinsics(1, np.diag([800.0, 800.0, 1.0]), image_size=(640, 480))
    message = msgpack.unpackb(encode(value))
    assert message["image_size"] == [640, 480]
    message["image_size"] = [640, "tall"]
    with pytest.raises(MeasurementError, match="image_size"):
        decode(msgpack.packb(message))
