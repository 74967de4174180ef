"""``tf2_msgs/msg/TFMessage`` to and from CDR bytes, with ``rosbags``' serialiser.

rmw_zenoh's payload is the message in CDR with the 4-byte encapsulation header (little-endian
CDR: ``00 01 00 00``), exactly what ``rosbags``' ``serialize_cdr`` writes and
``deserialize_cdr`` reads (``rosbags.typesys``, type store of ROS 2 Jazzy). A
:class:`Transform` is one ``geometry_msgs/msg/TransformStamped``: the pose of ``child`` in
``parent`` (``header.frame_id``), stamped ``stamp_ns`` (``header.stamp`` in Unix nanoseconds).

Decoding is total: a payload ``rosbags`` cannot read, or one with a non-finite number, a
zero quaternion, more than :data:`MAX_TRANSFORMS` transforms or more than
:data:`MAX_PAYLOAD_BYTES` bytes, raises :class:`TfDecodeError`. O(transforms) per message.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from typing import Any

from ubitrack_agent.io.ros2.keys import TF_TYPE

MAX_PAYLOAD_BYTES = 1 << 20
"""Largest TFMessage accepted (a tf tree of thousands of frames is a few hundred kB)."""
MAX_TRANSFORMS = 10_000
_NS = 1_000_000_000


class TfDecodeError(ValueError):
    """A payload is not a valid TFMessage in CDR; the message says how."""


@dataclass(frozen=True)
class Transform:
    """Pose of frame ``child`` in frame ``parent`` at ``stamp_ns``: ``translation`` in metres,
    ``rotation`` a unit quaternion ``(x, y, z, w)``."""

    parent: str
    child: str
    stamp_ns: int
    translation: tuple[float, float, float]
    rotation: tuple[float, float, float, float]


@cache
def typestore() -> Any:
    """rosbags' type store of ROS 2 Jazzy (built once, on first use)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def encode_tf(transforms: Sequence[Transform]) -> bytes:
    """One TFMessage holding ``transforms``, in CDR with its encapsulation header."""
    types = typestore().types
    time, header = types["builtin_interfaces/msg/Time"], types["std_msgs/msg/Header"]
    vector, quaternion = types["geometry_msgs/msg/Vector3"], types["geometry_msgs/msg/Quaternion"]
    pose, stamped = (
        types["geometry_msgs/msg/Transform"],
        types["geometry_msgs/msg/TransformStamped"],
    )
    message = types[TF_TYPE](
        transforms=[
            stamped(
                header=header(
                    stamp=time(sec=t.stamp_ns // _NS, nanosec=t.stamp_ns % _NS), frame_id=t.parent
                ),
                child_frame_id=t.child,
                transform=pose(
                    translation=vector(*map(float, t.translation)),
                    rotation=quaternion(*map(float, t.rotation)),
                ),
            )
            for t in transforms
        ]
    )
    return bytes(typestore().serialize_cdr(message, TF_TYPE))


def decode_tf(payload: bytes) -> list[Transform]:
    """The transforms of one TFMessage in CDR; :class:`TfDecodeError` if it is not one."""
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise TfDecodeError(f"{len(payload)} bytes, more than {MAX_PAYLOAD_BYTES}")
    try:
        message = typestore().deserialize_cdr(payload, TF_TYPE)
    except Exception as exc:  # rosbags' own errors on hostile bytes are of many types
        raise TfDecodeError(f"not a TFMessage in CDR ({type(exc).__name__}: {exc})") from None
    if len(message.transforms) > MAX_TRANSFORMS:
        raise TfDecodeError(f"{len(message.transforms)} transforms, more than {MAX_TRANSFORMS}")
    return [_transform(stamped) for stamped in message.transforms]


def _transform(stamped: Any) -> Transform:
    t, q = stamped.transform.translation, stamped.transform.rotation
    translation = (t.x, t.y, t.z)
    rotation = (q.x, q.y, q.z, q.w)
    if not all(math.isfinite(v) for v in (*translation, *rotation)):
        raise TfDecodeError(f"{stamped.child_frame_id[:60]!r}: a number is not finite")
    norm = math.sqrt(sum(v * v for v in rotation))
    if norm < 1e-6:
        raise TfDecodeError(f"{stamped.child_frame_id[:60]!r}: zero quaternion")
    stamp = stamped.header.stamp
    return Transform(
        stamped.header.frame_id,
        stamped.child_frame_id,
        int(stamp.sec) * _NS + int(stamp.nanosec),
        translation,
        tuple(v / norm for v in rotation),  # type: ignore[arg-type]
    )
