"""Recordings (``ubitrack_agent.io.recording``): a bit-exact round trip through the MCAP file,
and every malformed file (truncated, another profile, wrong schemas, hostile contents, random
bytes; hypothesis-generated) refused with a :class:`RecordingError`, never a crash."""

from __future__ import annotations

import io
import json
import sys

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

pytest.importorskip("mcap", reason='needs the mcap extra: pip install "ubitrack-agent[mcap]"')
pytest.importorskip("foxglove_schemas_protobuf", reason="needs the mcap extra")

from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from mcap.reader import make_reader
from mcap.writer import Writer

from ubitrack_agent.core import ErrorPose, Position2D, Position3D, encode
from ubitrack_agent.io.provider import EdgeAnnouncement
from ubitrack_agent.io.recording.fragments import Announced, parse_fragment
from ubitrack_agent.io.recording.layout import (
    ANNOUNCEMENT_SCHEMA,
    ANNOUNCEMENT_SCHEMA_NAME,
    ANNOUNCEMENTS_TOPIC,
    RecordingError,
)
from ubitrack_agent.io.recording.reader import (
    Announcement,
    Sample,
    Withdrawal,
    read_recording,
)
from ubitrack_agent.io.recording.writer import RecordingWriter

TRACKER = Announced(
    "ART",
    "lab",
    (
        EdgeAnnouncement("ART", "HT", "6D", rate=60.0, sigma=0.0005),
        EdgeAnnouncement("ART", "WT", "6D", static=True),
        EdgeAnnouncement("ART", "M1", "3D"),
    ),
)
CAMERA = Announced("camera", "lab", (EdgeAnnouncement("IP", "F1", "2D", rate=30.0),))


def pose(t: int, x: float) -> ErrorPose:
    rotation = np.array([0.1, -0.2, 0.3, 0.9])
    return ErrorPose(
        t,
        rotation / np.linalg.norm(rotation),
        np.array([x, 1 / 3, -2.5]),
        np.eye(6) * 1e-7 * (1 + x),
    )


class Clock:
    """Log times 1 ms apart."""

    def __init__(self) -> None:
        self.now = 1_700_000_000_000_000_000

    def __call__(self) -> int:
        self.now += 1_000_000
        return self.now


def recording() -> tuple[bytes, list]:
    """A small recording and what was written to it, in order."""
    stream = io.BytesIO()
    writer = RecordingWriter(stream, Clock())
    written: list = []
    writer.announced(TRACKER)
    writer.announced(CAMERA)
    written += [("announced", TRACKER), ("announced", CAMERA)]
    for i in range(20):
        value = pose(1_000 + i, i * 0.001)
        assert writer.measured("ART", "ART_HT", encode(value), value)
        written.append(("ART", "ART_HT", encode(value)))
        point = Position3D(2_000 + i, np.array([i, 0.5, 1e-9]), np.eye(3) * 1e-6)
        assert writer.measured("ART", "ART_M1", encode(point), point)
        written.append(("ART", "ART_M1", encode(point)))
        feature = Position2D(3_000 + i, np.array([320.25, 240.125 + i]))
        assert writer.measured("camera", "IP_F1", encode(feature), feature)
        written.append(("camera", "IP_F1", encode(feature)))
    writer.withdrawn("camera")
    written.append(("withdrawn", "camera"))
    assert not writer.measured("camera", "IP_F1", encode(feature), feature)  # not announced now
    assert not writer.measured("ART", "ART_HT", encode(feature), feature)  # wrong type
    assert writer.counters["not_announced"] == 2
    writer.finish()
    return stream.getvalue(), written


DATA, WRITTEN = recording()


def events(data: bytes) -> list:
    return list(read_recording(io.BytesIO(data)))


def test_round_trip_is_exact_and_in_order():
    read = events(DATA)
    assert len(read) == len(WRITTEN)
    for event, written in zip(read, WRITTEN, strict=True):
        if isinstance(event, Announcement):
            assert written == ("announced", event.announced)
        elif isinstance(event, Withdrawal):
            assert written == ("withdrawn", event.provider)
        else:
            assert isinstance(event, Sample)
            assert (event.provider, event.edge_name, encode(event.measurement)) == written
    log_times = [event.log_time_ns for event in read]
    assert log_times == sorted(log_times)


def test_frame_transform_channels_hold_the_poses():
    reader = make_reader(io.BytesIO(DATA))
    summary = reader.get_summary()
    topics = {channel.topic for channel in summary.channels.values()}
    assert "/ubitrack/tf/ART/ART_HT" in topics and "/ubitrack/tf/ART/ART_M1" in topics
    assert "/ubitrack/tf/camera/IP_F1" not in topics  # 2D: no transform
    transforms = [
        FrameTransform.FromString(message.data)
        for _, _, message in reader.iter_messages(topics=["/ubitrack/tf/ART/ART_HT"])
    ]
    assert len(transforms) == 20
    last, expected = transforms[-1], pose(1_019, 0.019)
    assert (last.parent_frame_id, last.child_frame_id) == ("ART", "HT")
    assert last.timestamp.ToNanoseconds() == 1_019
    assert [
        last.translation.x,
        last.translation.y,
        last.translation.z,
    ] == expected.translation.tolist()
    q = [last.rotation.x, last.rotation.y, last.rotation.z, last.rotation.w]
    assert q == expected.rotation.tolist()


def refused(data: bytes) -> str:
    with pytest.raises(RecordingError) as caught:
        events(data)
    return str(caught.value)


def test_every_truncation_is_refused():
    for cut in range(0, len(DATA) - 1, 13):
        refused(DATA[:cut])
    assert "truncated" in refused(DATA[: len(DATA) // 2])


def foreign_file(
    profile: str = "ubitrack",
    encoding: str = "json",
    schema: str = ANNOUNCEMENT_SCHEMA_NAME,
    payload: bytes = b"{}",
    sample: tuple[str, bytes] | None = None,
) -> bytes:
    """A file written with MCAP's own writer: one message on the announcement channel and,
    with ``sample = (edge type, payload)``, one on the data channel of edge ``p/e``."""
    stream = io.BytesIO()
    writer = Writer(stream)
    writer.start(profile=profile)
    schema_id = writer.register_schema(schema, "jsonschema", ANNOUNCEMENT_SCHEMA)
    channel = writer.register_channel(ANNOUNCEMENTS_TOPIC, encoding, schema_id)
    writer.add_message(channel, 1, payload, 1)
    if sample is not None:
        metadata = {"provider": "p", "edge": "e", "type": sample[0], "format_version": "1"}
        data = writer.register_channel("/ubitrack/data/p/e", "msgpack", 0, metadata)
        writer.add_message(data, 2, sample[1], 2)
    writer.finish()
    return stream.getvalue()


def test_another_profile_or_schema_is_refused():
    assert "profile 'ros2'" in refused(foreign_file(profile="ros2"))
    assert "wrong schema" in refused(foreign_file(encoding="cbor"))
    assert "wrong schema" in refused(foreign_file(schema="foxglove.Log"))


def announcement(fragment) -> bytes:
    return json.dumps({"event": "announced", "provider": "p", "fragment": fragment}).encode()


def test_hostile_announcements_are_refused_with_the_reason():
    valid = {"provider": "p", "edges": [{"name": "e", "from": "A", "to": "B", "type": "6D"}]}
    [event] = events(foreign_file(payload=announcement(valid)))
    assert event.announced.edges[0] == EdgeAnnouncement("A", "B", "6D", name="e")
    assert "withdrawal" in refused(foreign_file(payload=b'{"event": "withdrawn", "provider": "p"}'))
    assert "not JSON" in refused(foreign_file(payload=b"{"))
    bad_edges = [
        ({"name": "e", "from": "A/B", "to": "B", "type": "6D"}, "'/'"),
        ({"name": "e", "from": "A", "to": "B", "type": "7D"}, "edge type"),
        ({"name": "e", "from": "A", "to": "B", "type": "6D", "rate": -1}, "rate"),
        ({"name": "e", "from": "A", "to": "B", "type": "6D", "rate": True}, "rate"),
        ({"name": "e", "from": "A", "to": "B", "type": "6D", "static": "yes"}, "static"),
        ({"name": "e", "from": "A", "to": "B", "type": "6D", "x": 1}, "unknown fields"),
    ]
    for edge, reason in bad_edges:
        assert reason in refused(
            foreign_file(payload=announcement({"provider": "p", "edges": [edge]}))
        )
    named_other = {**valid, "provider": "q"}
    assert "names another" in refused(foreign_file(payload=announcement(named_other)))


def with_sample(payload: bytes, edge_type: str = "6D") -> bytes:
    """A recording of one announced 6D edge ``p/e`` and one message on its data channel
    claiming ``edge_type``."""
    fragment = {"provider": "p", "edges": [{"name": "e", "from": "A", "to": "B", "type": "6D"}]}
    return foreign_file(payload=announcement(fragment), sample=(edge_type, payload))


def test_hostile_measurements_are_refused():
    good = encode(pose(5, 0.0))
    assert isinstance(events(with_sample(good))[-1], Sample)
    assert "channel of type '2D', edge 6D" in refused(with_sample(good, "2D"))
    message = msgpack.unpackb(good)
    message["translation"] = np.array([np.nan, 0.0, 0.0]).tobytes()
    assert "NaN" in refused(with_sample(msgpack.packb(message)))
    assert "(edge 'p'/'e')" in refused(with_sample(b"\xc1"))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=400))
def test_random_payloads_are_refused_or_decoded(payload):
    try:
        read = events(with_sample(payload))
    except RecordingError:
        return
    assert isinstance(read[-1], Sample)  # a payload that decodes is a measurement


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
    lambda children: (
        st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=6), children, max_size=4)
    ),
    max_leaves=20,
)
edge_like = st.fixed_dictionaries(
    {
        "name": st.sampled_from(["e", "f", "a/b", ""]),
        "from": st.sampled_from(["A", "B", "*"]),
        "to": st.sampled_from(["B", "C"]),
        "type": st.sampled_from(["6D", "3D", "2D", "x"]),
    },
    optional={
        "static": json_values,
        "mode": st.sampled_from(["push", "pull", "x"]) | json_values,
        "rate": json_values,
        "sigma": json_values,
        "latency": json_values,
    },
)


@settings(max_examples=300, deadline=None)
@given(
    st.one_of(
        json_values,
        st.fixed_dictionaries(
            {
                "provider": st.sampled_from(["p", "q/r", 5]),
                "edges": st.lists(edge_like | json_values, max_size=3),
            },
            optional={"host": json_values},
        ),
    )
)
def test_any_fragment_parses_or_is_refused(fragment):
    try:
        announced = parse_fragment(fragment)
    except RecordingError:
        return
    assert parse_fragment(announced.as_json()) == announced


@settings(max_examples=200, deadline=None)
@given(st.data())
def test_damaged_files_are_refused_or_read(data):
    damaged = bytearray(DATA)
    for _ in range(data.draw(st.integers(1, 4))):
        damaged[data.draw(st.integers(0, len(DATA) - 1))] = data.draw(st.integers(0, 255))
    try:
        read = events(bytes(damaged))
    except RecordingError:
        return
    assert len(read) <= len(WRITTEN)  # damage the CRCs do not see: a field, a dropped record


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=300))
def test_random_files_are_refused(blob):
    with pytest.raises(RecordingError):
        events(b"\x89MCAP0\r\n" + blob)


@pytest.mark.parametrize("command", ["record", "replay"])
def test_a_missing_extra_is_named(command, monkeypatch, capsys, tmp_path):
    from ubitrack_agent import cli

    for name in [n for n in sys.modules if n.startswith("ubitrack_agent.io.recording")]:
        monkeypatch.delitem(sys.modules, name)
    for name in [n for n in sys.modules if n == "mcap" or n.startswith("mcap.")]:
        monkeypatch.setitem(sys.modules, name, None)  # as if not installed: imports fail
    monkeypatch.setitem(sys.modules, "mcap", None)
    # Should the import succeed after all, the command ends at once on a port nobody uses.
    isolated = ["--connect", "tcp/127.0.0.1:9", "--domain", "nowhere"]
    assert cli.main([command, str(tmp_path / "file.mcap"), *isolated]) == 2
    err = capsys.readouterr().err
    assert "needs the mcap extra (mcap" in err
    assert 'pip install "ubitrack-agent[mcap]"' in err


def test_a_gap_of_centuries_is_waited_out_not_an_overflow():
    import threading

    from ubitrack_agent.io.recording.replayer import Replayer
    from ubitrack_agent.net.keys import KeySpace

    stop = threading.Event()
    replayer = Replayer(None, KeySpace("ubitrack/test"), "lab", stop=stop)  # no provider opened
    threading.Timer(0.2, stop.set).start()
    far = [Withdrawal(0, "nobody"), Withdrawal(2**64 - 1, "nobody")]  # an MCAP log time's most
    assert replayer.play(far) is False  # stopped while waiting
    assert replayer.counters["withdrawn"] == 1 and replayer.counters["passes"] == 0
