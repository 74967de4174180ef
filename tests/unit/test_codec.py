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
    codec,
    decode,
    encode,
)
from ubitrack_agent.core.measurements import (
    FULL,
    MAX_TIMESTAMP_NS,
    MEASUREMENT_TYPES,
    OPENCV_DISTORTION_LENGTHS,
    WORKER,
)

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
    st.builds(
        ErrorPose, timestamps, quaternions(), vectors(3), covariances(6), st.none() | covariances(6)
    ),
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


# -- hostile messages: what a fuzz run against a live worker sends ------------------------------
# Each generator starts from a valid message and breaks one thing the way an attacker or a
# buggy sensor would; decode must return a valid measurement or raise MeasurementError.

HUGE_FLOATS = (1e308, -1e308, float("inf"), float("-inf"), float("nan"), 5e-324, -0.0)
HUGE_INTS = (2**63 - 1, 2**63, 2**64 - 1, -(2**63), -1, -(2**31))


def _fields(value: Measurement) -> tuple[dict, list]:
    """The unpacked message of ``value`` and the names of its array fields present."""
    message = msgpack.unpackb(encode(value))
    return message, [spec.name for spec in value.ARRAY_FIELDS if spec.name in message]


def _packed(message: dict) -> bytes:
    return msgpack.packb(message, use_bin_type=True)


@st.composite
def reshaped_fields(draw):
    """An array field holding a multiple or a fraction of its values (6 floats for a
    3-vector, 72 for a 6x6 covariance, 2 for a quaternion, none at all)."""
    message, names = _fields(draw(measurements))
    name = draw(st.sampled_from(names))
    values = np.frombuffer(message[name], dtype="<f8")
    size = max(values.size, 1)
    count = draw(
        st.sampled_from([0, 1, size // 2, size - 1, size + 1, 2 * size, 3 * size, 12 * size])
        | st.integers(0, 16 * size)
    )
    message[name] = np.resize(values if values.size else np.ones(1), count).tobytes()
    return _packed(message)


@st.composite
def truncated_messages(draw):
    """A valid message cut anywhere, or one of its arrays cut anywhere."""
    raw = encode(draw(measurements))
    if draw(st.booleans()):
        return raw[: draw(st.integers(0, len(raw) - 1))]
    message, names = _fields(draw(measurements))
    name = draw(st.sampled_from(names))
    message[name] = message[name][: draw(st.integers(0, max(len(message[name]) - 1, 0)))]
    return _packed(message)


def _nest(value, depth: int, as_map: bool):
    for _ in range(depth):
        value = {"k": value} if as_map else [value]
    return value


@st.composite
def nested_messages(draw):
    """msgpack maps and lists nested deeply: as the whole message, or as a field's value."""
    depth = draw(st.integers(1, 3000))
    as_map = draw(st.booleans())
    if draw(st.booleans()):
        # Raw bytes: one-element fixarrays / fixmaps nested ``depth`` deep, built without
        # recursion (msgpack.packb itself refuses nesting this deep).
        head = (b"\x81\xa1k" if as_map else b"\x91") * depth
        return head + b"\xc0"
    message, names = _fields(draw(measurements))
    name = draw(st.sampled_from([*names, "t", "v", "type", "image_size"]))
    message[name] = _nest(draw(st.sampled_from([1, 1.0, b"", "x"])), min(depth, 500), as_map)
    return _packed(message)


@st.composite
def huge_numbers(draw):
    """Overflowing, infinite and NaN numbers in arrays, timestamps and the version."""
    message, names = _fields(draw(measurements))
    choice = draw(st.sampled_from(["array", "t", "v", "image_size"]))
    if choice == "array":
        name = draw(st.sampled_from(names))
        values = np.frombuffer(message[name], dtype="<f8").copy()
        if values.size:
            index = draw(st.integers(0, values.size - 1))
            values[index] = draw(st.sampled_from(HUGE_FLOATS))
            if draw(st.booleans()):
                values[:] = draw(st.sampled_from(HUGE_FLOATS))
        message[name] = values.tobytes()
    else:
        number = st.sampled_from(HUGE_INTS) | st.sampled_from(HUGE_FLOATS)
        message[choice] = draw(number if choice != "image_size" else st.lists(number, max_size=3))
    return _packed(message)


@st.composite
def wrong_but_valid_values(draw):
    """Well-formed messages with values no sensor should send: non-unit quaternions,
    covariances that are not positive semi-definite or not symmetric, timestamps below zero
    or at and beyond the int64 bound."""
    timestamp = draw(
        st.sampled_from([-1, 0, 2**63 - 2, 2**63 - 1, 2**63, 2**64 - 1])
        | st.integers(-(2**63), 2**64 - 1)
    )
    kind = draw(st.sampled_from(["quaternion", "covariance", "timestamp"]))
    if kind == "quaternion":
        q = draw(vectors(4)) * draw(st.sampled_from([0.0, 0.5, 1.0 + 1e-5, 2.0, 1e300]))
        value = {"type": "Rotation3D", "rotation": q.tobytes()}
    elif kind == "covariance":
        a = draw(covariances(6))
        a[draw(st.integers(0, 5)), draw(st.integers(0, 5))] += draw(st.sampled_from([-1.0, 1e3]))
        a = a - np.eye(6) * draw(st.floats(0.0, 10.0))
        value = {
            "type": "ErrorPose",
            "rotation": np.array([0.0, 0.0, 0.0, 1.0]).tobytes(),
            "translation": np.zeros(3).tobytes(),
            "covariance": a.tobytes(),
        }
    else:
        value = {"type": "Pose", "rotation": np.array([0.0, 0.0, 0.0, 1.0]).tobytes()}
        value["translation"] = np.zeros(3).tobytes()
    return _packed({"v": 1, "t": timestamp, **value})


hostile_messages = st.one_of(
    reshaped_fields(),
    truncated_messages(),
    nested_messages(),
    huge_numbers(),
    wrong_but_valid_values(),
)


@settings(max_examples=600)
@given(hostile_messages)
def test_hostile_messages_decode_validly_or_are_rejected_cleanly(data: bytes):
    try:
        decoded = decode(data)
    except MeasurementError:
        return
    assert decode(encode(decoded)) == decoded


@pytest.mark.parametrize(
    "tag, field_name, count",
    [
        ("Pose", "translation", 6),
        ("Pose", "rotation", 8),
        ("ErrorPose", "covariance", 72),
        ("Position2D", "position", 4),
        ("Projection", "matrix", 24),
        ("CameraIntrinsics", "matrix", 18),
    ],
)
def test_a_multiple_of_a_fixed_shape_is_rejected(tag, field_name, count):
    message = {
        "v": 1,
        "type": tag,
        "t": 1,
        "rotation": np.array([0.0, 0.0, 0.0, 1.0]).tobytes(),
        "translation": np.zeros(3).tobytes(),
        "covariance": np.eye(6).tobytes(),
        "position": np.zeros(2).tobytes(),
        "matrix": np.eye(3, 4).tobytes(),
        "distortion": b"",
    }
    keep = {f.name for f in MEASUREMENT_TYPES[tag].ARRAY_FIELDS} | {"v", "type", "t"}
    message = {k: v for k, v in message.items() if k in keep}
    message[field_name] = np.zeros(count).tobytes()
    with pytest.raises(MeasurementError, match=f"{count} values do not fit"):
        decode(_packed(message))


def _outcome(read, data: bytes) -> tuple[str, object]:
    try:
        return "value", read(data)
    except MeasurementError as exc:
        return "error", str(exc)


@settings(max_examples=400)
@given(st.one_of(measurements.map(encode), hostile_messages), st.sampled_from([FULL, WORKER]))
def test_the_canonical_reader_decides_as_the_general_reader(data: bytes, level: str):
    """``decode`` reads an encoder's message in one pass (``codec._Canonical``): it must
    accept, build and refuse exactly what the general reader does, with the same error."""
    canonical = _outcome(lambda d: decode(d, level=level), data)
    general = _outcome(lambda d: codec._read(codec._unpack(d), None, level), data)
    assert canonical[0] == general[0]
    if canonical[0] == "value":
        assert type(canonical[1]) is type(general[1]) and canonical[1] == general[1]
    else:
        assert canonical[1] == general[1]


def test_a_field_swapped_for_an_unknown_key_is_refused_by_both_readers():
    """The one-pass reader counts the keys instead of comparing them: as many keys as
    expected, one of them unknown, must still go to the general reader and be refused."""
    message = msgpack.unpackb(encode(ErrorPose(1, [0, 0, 0, 1], [1, 2, 3], np.eye(6))))
    message["extra"] = message.pop("covariance")
    assert codec._canonical(message, None).read(message, WORKER) is None
    with pytest.raises(MeasurementError, match="unknown keys"):
        decode(_packed(message), level=WORKER)


@pytest.mark.parametrize("key", [1, 2.5, None, True])
def test_a_map_with_a_key_that_is_no_string_is_refused(key):
    """msgpack's default ``strict_map_key`` (relied on by ``codec._unpack``) refuses it."""
    data = msgpack.packb({"v": 1, "type": "Pose", "t": 1, key: b""}, strict_types=False)
    with pytest.raises(MeasurementError, match="not valid msgpack"):
        decode(data)


def test_text_is_read_as_text():
    """msgpack's default ``raw=False`` (relied on by ``codec._unpack``): a type tag sent as
    text is a str, so the message is read; sent as bytes, it is no type tag."""
    pose = msgpack.unpackb(encode(Pose(1, [0, 0, 0, 1], [1, 2, 3])))
    assert isinstance(decode(_packed(pose)), Pose)
    pose["type"] = b"Pose"
    with pytest.raises(MeasurementError, match="unknown measurement type"):
        decode(_packed(pose))


def test_an_encoders_message_takes_the_canonical_reader():
    """The one-pass reader serves every fixed-shape type as the encoder writes it (else the
    lean path would silently not be taken), with or without its optional fields."""
    for value in (
        ErrorPose(1, [0, 0, 0, 1], [1, 2, 3], np.eye(6)),
        ErrorPose(1, [0, 0, 0, 1], [1, 2, 3], np.eye(6), 0.5 * np.eye(6)),
        Position3D(1, [1, 2, 3]),
        Position3D(1, [1, 2, 3], np.eye(3)),
    ):
        message = msgpack.unpackb(encode(value))
        reader = codec._canonical(message, None)
        assert reader is not None and reader.read(message, WORKER) == value
    assert {tag for tag, _ in codec._CANONICAL} == {
        "Pose",
        "ErrorPose",
        "Position3D",
        "Position2D",
        "Rotation3D",
        "Projection",
    }


@st.composite
def error_pose_runs(draw):
    """A worker's backlog: encoded ErrorPoses, some broken as a sensor or an attacker would
    (an indefinite or asymmetric covariance, a quaternion off unit length by about the
    tolerance either way or with components whose squares overflow, NaN or infinity, a hostile
    message)."""
    count = draw(st.integers(1, 24))
    payloads = []
    for _ in range(count):
        value = draw(
            st.builds(
                ErrorPose,
                timestamps,
                quaternions(),
                vectors(3),
                covariances(6),
                st.none() | covariances(6),
            )
        )
        payload = encode(value)
        broken = draw(
            st.sampled_from(
                ["no", "no", "no", "indefinite", "asymmetric", "infinite", "hostile", "norm"]
            )
        )
        if broken == "hostile":
            payload = draw(hostile_messages)
        elif broken == "norm":
            message = msgpack.unpackb(payload)
            factor = draw(st.sampled_from([1e200, 1e-200]) | st.floats(1 - 3e-6, 1 + 3e-6))
            message["rotation"] = (value.rotation * factor).tobytes()
            payload = _packed(message)
        elif broken == "infinite":
            message = msgpack.unpackb(payload)
            name = draw(st.sampled_from(["rotation", "translation", "covariance"]))
            values = np.frombuffer(message[name]).copy()
            values[draw(st.integers(0, values.size - 1))] = draw(st.sampled_from(HUGE_FLOATS[2:5]))
            message[name] = values.tobytes()
            payload = _packed(message)
        elif broken != "no":
            message = msgpack.unpackb(payload)
            cov = value.covariance.copy()
            if broken == "indefinite":
                cov[0, 0] = -abs(cov[0, 0]) - draw(st.floats(1e-6, 1e3))
            else:
                cov[0, 1] += draw(st.floats(1e-3, 1e3))
            message["covariance"] = cov.tobytes()
            payload = _packed(message)
        payloads.append(payload)
    return payloads


@settings(max_examples=300)
@given(
    error_pose_runs() | st.lists(st.one_of(measurements.map(encode), hostile_messages), max_size=8),
    st.sampled_from([FULL, WORKER]),
    st.sampled_from([None, (Pose, ErrorPose)]),
)
def test_a_run_decodes_as_each_message_alone(payloads: list[bytes], level: str, expected):
    """``decode_run`` (a worker's backlog, its numbers and covariances checked together)
    gives each message what ``decode`` gives it: the same measurement or the same error."""
    run = codec.decode_run(payloads, expected, level)
    assert len(run) == len(payloads)
    for data, got in zip(payloads, run, strict=True):
        alone = _outcome(lambda d: decode(d, expected, level), data)
        if alone[0] == "value":
            assert type(got) is type(alone[1]) and got == alone[1]
            assert all(not a.flags.writeable for a in vars(got).values() if hasattr(a, "flags"))
        else:
            assert isinstance(got, MeasurementError) and str(got) == alone[1]


def test_a_run_refuses_only_its_indefinite_covariance_with_the_error_decode_gives():
    good = [encode(ErrorPose(i, [0, 0, 0, 1], [1, 2, 3], np.eye(6))) for i in range(9)]
    message = msgpack.unpackb(good[4])
    message["covariance"] = (np.eye(6) - 2 * np.eye(6)[3]).tobytes()
    good[4] = _packed(message)
    run = codec.decode_run(good, ErrorPose, WORKER)
    assert [isinstance(value, ErrorPose) for value in run] == [True] * 4 + [False] + [True] * 4
    with pytest.raises(MeasurementError) as refused:
        decode(good[4], ErrorPose, WORKER)
    assert str(run[4]) == str(refused.value) and "positive semi-definite" in str(run[4])
