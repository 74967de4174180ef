"""``io.ros2.provider.TfAdapter``: rosbags-serialised TFMessages with rmw_zenoh attachments in,
SRG edges and poses out; hostile samples rejected, typed and counted, never raised."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

rosbags_typesys = pytest.importorskip(
    "rosbags.typesys", reason="the ros2 extra (rosbags) is not installed"
)
zenoh_ext = pytest.importorskip("zenoh.ext")

from ubitrack_agent.core import ErrorPose  # noqa: E402
from ubitrack_agent.io.ros2.cdr import decode_tf  # noqa: E402
from ubitrack_agent.io.ros2.frames import FrameNames  # noqa: E402
from ubitrack_agent.io.ros2.keys import TF_TYPE  # noqa: E402
from ubitrack_agent.io.ros2.provider import TfAdapter  # noqa: E402
from ubitrack_agent.io.ros2.subscriber import TfSample  # noqa: E402

JAZZY = rosbags_typesys.get_typestore(rosbags_typesys.Stores.ROS2_JAZZY)
RECEIVED_NS = 1_800_000_000_000_000_000


def tf_payload(*transforms) -> bytes:
    t = JAZZY.types
    message = t[TF_TYPE](
        transforms=[
            t["geometry_msgs/msg/TransformStamped"](
                header=t["std_msgs/msg/Header"](
                    stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=0), frame_id=parent
                ),
                child_frame_id=child,
                transform=t["geometry_msgs/msg/Transform"](
                    translation=t["geometry_msgs/msg/Vector3"](*xyz),
                    rotation=t["geometry_msgs/msg/Quaternion"](0.0, 0.0, 0.0, 1.0),
                ),
            )
            for parent, child, sec, xyz in transforms
        ]
    )
    return bytes(JAZZY.serialize_cdr(message, TF_TYPE))


def attachment(sequence: int = 1) -> bytes:
    Int64 = zenoh_ext.Int64
    return zenoh_ext.z_serialize(
        ("sequence_number", Int64(sequence), "source_timestamp", Int64(7), "source_gid", bytes(16))
    ).to_bytes()


class Published:
    """What the adapter hands its publisher (the provider, in the command)."""

    def __init__(self) -> None:
        self.items: list = []

    def publish(self, edge_name, measurement) -> None:
        self.items.append((edge_name, measurement))


def test_transforms_become_edges_static_or_dynamic_by_topic():
    adapter = TfAdapter(FrameNames(prefix="ros."))
    out = Published()
    static = TfSample(True, tf_payload(("map", "odom", 0, (1, 0, 0))), attachment(), RECEIVED_NS)
    dynamic = TfSample(
        False, tf_payload(("odom", "robot1/base", 1_700_000_000, (0, 2, 0))), attachment(), 5
    )
    assert adapter.handle(static, static.received_ns, out) == 1
    assert adapter.handle(dynamic, dynamic.received_ns, out) == 1
    edges = {(e.source, e.target): e.static for e in adapter.edges}
    assert edges == {("ros.map", "ros.odom"): True, ("ros.odom", "ros.robot1.base"): False}
    (name0, pose0), (_, pose1) = out.items
    assert name0 == "ros.map_ros.odom" and isinstance(pose0, ErrorPose)
    assert pose0.timestamp_ns == RECEIVED_NS  # a zero stamp gets the receive time
    assert pose1.timestamp_ns == 1_700_000_000 * 10**9  # the header stamp
    np.testing.assert_allclose(pose1.translation, [0, 2, 0])


def test_a_pair_on_both_topics_and_refused_names_are_left_out_and_counted():
    adapter = TfAdapter()
    out = Published()
    adapter.handle(TfSample(True, tf_payload(("a", "b", 1, (0, 0, 0))), attachment(), 1), 1, out)
    both = tf_payload(
        ("a", "b", 2, (0, 0, 0)), ("a", "bad frame", 2, (0, 0, 0)), ("c", "c", 2, (0, 0, 0))
    )
    assert adapter.handle(TfSample(False, both, attachment(2), 2), 2, out) == 0
    assert adapter.counters["static_and_dynamic"] == 1
    assert adapter.counters["refused_frame"] == 1
    assert adapter.counters["self_transform"] == 1
    assert len(adapter.edges) == 1


def test_a_sample_without_attachment_is_rejected_as_rmw_zenoh_does():
    adapter = TfAdapter()
    sample = TfSample(False, tf_payload(("a", "b", 1, (0, 0, 0))), None, 1)
    assert adapter.handle(sample, 1, Published()) == 0
    assert adapter.counters["rejected"] == adapter.counters["rejected_attachment"] == 1


@settings(max_examples=300)
@given(
    payload=st.one_of(
        st.binary(max_size=300),
        st.builds(
            lambda cut, flip: bytes(
                b ^ 0xFF if i == flip else b
                for i, b in enumerate(tf_payload(("map", "odom", 3, (1, 2, 3)))[:cut])
            ),
            st.integers(0, 200),
            st.integers(0, 200),
        ),
    ),
    extra=st.one_of(st.none(), st.binary(max_size=80), st.just(attachment())),
)
def test_hostile_samples_are_counted_never_raised(payload, extra):
    adapter = TfAdapter()
    published = adapter.handle(TfSample(False, payload, extra, 1), 1, Published())
    counters = adapter.counters
    assert counters["received"] == 1
    if counters["rejected"]:
        assert published == 0 and counters["rejected"] == 1
        assert counters["rejected_attachment"] + counters["rejected_payload"] == 1
        return
    left_out = sum(counters[k] for k in ("refused_frame", "self_transform", "invalid_transform"))
    assert published + left_out == len(decode_tf(payload))
