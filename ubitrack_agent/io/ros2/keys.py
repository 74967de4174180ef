"""Where rmw_zenoh puts a topic's samples: ``<domain>/<topic>/<DDS type name>/<type hash>``.

rmw_zenoh (Jazzy and later, ``rmw_zenoh_cpp/src/detail/liveliness_utils.cpp``, ``TopicInfo``)
builds a topic's data key from the ROS domain id, the topic name without its outer slashes,
the type's DDS-style name (``tf2_msgs::msg::dds_::TFMessage_``) and the type's RIHS01 hash
(REP 2011: SHA-256 over the type description), e.g.
``0/tf/tf2_msgs::msg::dds_::TFMessage_/RIHS01_e369...``. Humble's rmw_zenoh has no hash in the
key and does not interoperate with Jazzy; this bridge speaks Jazzy's format.

The hash of ``tf2_msgs/msg/TFMessage`` is a constant of the wire format (the type has not
changed since its description was first hashed); the unit tests check it against the hash
``rosbags`` computes from its own type store.
"""

from __future__ import annotations

TF_TYPE = "tf2_msgs/msg/TFMessage"
TF_TYPE_HASH = "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"
TF_TOPIC = "/tf"
TF_STATIC_TOPIC = "/tf_static"

MAX_DOMAIN_ID = 232
"""Largest ROS domain id (ROS 2's documented range is 0-232; rmw_zenoh puts it in the key)."""


def check_domain_id(domain_id: int) -> int:
    """``domain_id`` if it is a ROS domain id (0..232), else ``ValueError``."""
    if isinstance(domain_id, bool) or not isinstance(domain_id, int):
        raise ValueError(f"ROS domain id must be an integer, got {domain_id!r}")
    if not 0 <= domain_id <= MAX_DOMAIN_ID:
        raise ValueError(f"ROS domain id {domain_id} is not in 0..{MAX_DOMAIN_ID}")
    return domain_id


def dds_type_name(typename: str) -> str:
    """``pkg/msg/Name`` as rmw_zenoh names it in keys: ``pkg::msg::dds_::Name_``."""
    package, kind, name = typename.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def topic_key(
    domain_id: int, topic: str, typename: str = TF_TYPE, type_hash: str = TF_TYPE_HASH
) -> str:
    """The zenoh key of ``topic``'s samples on ROS domain ``domain_id``."""
    name = topic.strip("/")
    if not name:
        raise ValueError(f"topic name {topic!r} is empty")
    return f"{check_domain_id(domain_id)}/{name}/{dds_type_name(typename)}/{type_hash}"
