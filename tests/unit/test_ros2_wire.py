"""The rmw_zenoh wire format of ``io.ros2`` checked against code nobody here wrote: rosbags'
type store (RIHS01 hash, CDR) and zenoh-ext's serializer (the attachment)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

rosbags_typesys = pytest.importorskip(
    "rosbags.typesys", reason="the ros2 extra (rosbags) is not installed"
)
zenoh_ext = pytest.importorskip("zenoh.ext")

from zenoh import ZBytes  # noqa: E402

from ubitrack_agent.io.ros2.attachment import (  # noqa: E402
    GID_BYTES,
    Attachment,
    AttachmentError,
    decode_attachment,
    encode_attachment,
)
from ubitrack_agent.io.ros2.cdr import TfDecodeError, Transform, decode_tf, encode_tf  # noqa: E402
from ubitrack_agent.io.ros2.frames import FrameNameError, FrameNames  # noqa: E402
from ubitrack_agent.io.ros2.keys import TF_TYPE, TF_TYPE_HASH, topic_key  # noqa: E402
from ubitrack_agent.io.ros2.liveliness import (  # noqa: E402
    PUBLISHER,
    TF_QOS,
    TF_STATIC_QOS,
    NodeIdentity,
)

Stores, get_typestore = rosbags_typesys.Stores, rosbags_typesys.get_typestore
JAZZY = get_typestore(Stores.ROS2_JAZZY)
INT64 = st.integers(min_value=-(2**63), max_value=2**63 - 1)


@pytest.mark.parametrize("store", ["ROS2_JAZZY", "ROS2_KILTED", "LATEST"])
def test_the_keys_type_hash_is_the_one_rosbags_computes(store):
    computed = get_typestore(Stores[store]).hash_rihs01(TF_TYPE)
    assert computed == TF_TYPE_HASH
    assert topic_key(0, "/tf") == f"0/tf/tf2_msgs::msg::dds_::TFMessage_/{computed}"
    assert topic_key(42, "/tf_static/").startswith("42/tf_static/tf2_msgs::msg::dds_::")


def test_a_domain_id_outside_ros_range_is_refused():
    with pytest.raises(ValueError, match=r"not in 0\.\.232"):
        topic_key(233, "/tf")


def rosbags_message(transforms):
    t = JAZZY.types
    return t[TF_TYPE](
        transforms=[
            t["geometry_msgs/msg/TransformStamped"](
                header=t["std_msgs/msg/Header"](
                    stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=parent
                ),
                child_frame_id=child,
                transform=t["geometry_msgs/msg/Transform"](
                    translation=t["geometry_msgs/msg/Vector3"](*xyz),
                    rotation=t["geometry_msgs/msg/Quaternion"](*q),
                ),
            )
            for parent, child, sec, nsec, xyz, q in transforms
        ]
    )


def test_our_payload_decodes_with_rosbags_into_the_transforms():
    ours = [
        Transform("world", "cam", 1_700_000_000_123_456_789, (1.0, -2.0, 0.5), (0, 0, 0.6, 0.8)),
        Transform("cam", "robot1/base", 5, (0.0, 0.0, 0.0), (1.0, 0, 0, 0)),
    ]
    payload = encode_tf(ours)
    assert payload[:4] == b"\x00\x01\x00\x00"  # CDR little-endian encapsulation header
    message = JAZZY.deserialize_cdr(payload, TF_TYPE)
    got = message.transforms
    assert [(s.header.frame_id, s.child_frame_id) for s in got] == [
        ("world", "cam"),
        ("cam", "robot1/base"),
    ]
    assert (got[0].header.stamp.sec, got[0].header.stamp.nanosec) == (1_700_000_000, 123_456_789)
    assert (got[1].header.stamp.sec, got[1].header.stamp.nanosec) == (0, 5)
    r = got[0].transform.rotation
    assert (r.x, r.y, r.z, r.w) == (0, 0, 0.6, 0.8)
    v = got[0].transform.translation
    assert (v.x, v.y, v.z) == (1.0, -2.0, 0.5)


def test_a_payload_rosbags_serialises_decodes_into_the_transforms():
    message = rosbags_message([("map", "odom", 12, 34, (1, 2, 3), (0, 0, 0, 2.0))])
    (transform,) = decode_tf(bytes(JAZZY.serialize_cdr(message, TF_TYPE)))
    assert transform == Transform("map", "odom", 12_000_000_034, (1, 2, 3), (0, 0, 0, 1.0))
    big_endian = bytes(JAZZY.serialize_cdr(message, TF_TYPE, little_endian=False))
    assert decode_tf(big_endian) == [transform]


@pytest.mark.parametrize("bad", [(0, 0, 0, 0), (math.nan, 0, 0, 1)])
def test_a_zero_or_nan_rotation_is_refused(bad):
    message = rosbags_message([("map", "odom", 1, 0, (1, 2, 3), bad)])
    with pytest.raises(TfDecodeError):
        decode_tf(bytes(JAZZY.serialize_cdr(message, TF_TYPE)))


@given(sequence=INT64, stamp=INT64, gid=st.binary(min_size=GID_BYTES, max_size=GID_BYTES))
def test_the_attachment_is_zenoh_ext_serialisation(sequence, stamp, gid):
    ours = encode_attachment(Attachment(sequence, stamp, gid))
    Int64 = zenoh_ext.Int64
    reference = zenoh_ext.z_serialize(
        ("sequence_number", Int64(sequence), "source_timestamp", Int64(stamp), "source_gid", gid)
    ).to_bytes()
    assert ours == reference
    assert decode_attachment(reference) == Attachment(sequence, stamp, gid)
    assert zenoh_ext.z_deserialize(tuple[str, Int64, str, Int64, str, bytes], ZBytes(ours)) == (
        "sequence_number",
        sequence,
        "source_timestamp",
        stamp,
        "source_gid",
        gid,
    )


@given(st.binary(max_size=200))
def test_any_bytes_as_attachment_give_a_typed_rejection(data):
    try:
        attachment = decode_attachment(data)
    except AttachmentError:
        return
    assert len(attachment.gid) == GID_BYTES


@given(st.binary(max_size=400))
def test_any_bytes_as_payload_give_a_typed_rejection(data):
    try:
        transforms = decode_tf(data)
    except TfDecodeError:
        return
    assert all(isinstance(t, Transform) for t in transforms)


def test_no_attachment_a_missing_gid_and_a_short_gid_are_refused():
    Int64 = zenoh_ext.Int64
    with pytest.raises(AttachmentError, match="no attachment"):
        decode_attachment(None)
    pairs = ("sequence_number", Int64(1), "source_timestamp", Int64(2))
    with pytest.raises(AttachmentError, match="ends inside a length"):
        decode_attachment(zenoh_ext.z_serialize(pairs).to_bytes())
    short_gid = zenoh_ext.z_serialize((*pairs, "source_gid", bytes(8))).to_bytes()
    with pytest.raises(AttachmentError, match="source_gid has 8 bytes"):
        decode_attachment(short_gid)


def test_liveliness_tokens_follow_rmw_zenohs_layout():
    node = NodeIdentity(3, "a1b2", "ubitrack_tf")
    assert node.node_token() == "@ros2_lv/3/a1b2/0/0/NN/%/%/ubitrack_tf"
    token = node.endpoint_token(2, PUBLISHER, "/tf_static", TF_TYPE, TF_TYPE_HASH, TF_STATIC_QOS)
    parts = token.split("/")
    assert len(parts) == 13 and all(parts)  # rmw_zenoh's Entity::make refuses empty parts
    assert parts[5] == "MP" and parts[9] == "%tf_static"
    assert parts[10] == "tf2_msgs::msg::dds_::TFMessage_" and parts[11] == TF_TYPE_HASH
    # reliability : durability : history,depth : deadline : lifespan : liveliness (3 fields)
    qos = parts[12].split(":")
    assert len(qos) == 6 and qos[1] == "1" and qos[2] == ",1"
    assert [len(q.split(",")) for q in qos] == [1, 1, 2, 2, 2, 3]
    assert TF_QOS.keyexpr().split(":")[:3] == ["", "", ",100"]
    with pytest.raises(ValueError):
        NodeIdentity(0, "a1", "bad-name")


def test_frame_names_map_both_ways_and_refuse_what_has_no_counterpart():
    names = FrameNames({"HT": "head_target"})
    assert names.to_ros("robot1.base_link") == "robot1/base_link"
    assert names.to_srg("robot1/base_link") == "robot1.base_link"
    assert names.to_srg("/odom") == "odom"
    assert names.to_ros("HT") == "head_target" and names.to_srg("head_target") == "HT"
    for srg in ("my-frame", "1st", "a..b"):
        with pytest.raises(FrameNameError):
            names.to_ros(srg)
    for ros in ("has space", "kamera\u00e4", "x" * 200):
        with pytest.raises(FrameNameError):
            names.to_srg(ros)
    prefixed = FrameNames(prefix="ros.")
    assert prefixed.to_srg("base_link") == "ros.base_link"
    assert prefixed.to_ros("ros.base_link") == "base_link"
    with pytest.raises(FrameNameError, match="prefix"):
        prefixed.to_ros("HT")
