"""The liveliness tokens by which ROS 2 (rmw_zenoh) discovers nodes, publishers and
subscriptions: ``ros2 topic list`` and ``ros2 node list`` see the bridge through them.

Key layout (rmw_zenoh ``docs/design.md`` "Graph Cache" and
``rmw_zenoh_cpp/src/detail/liveliness_utils.cpp``, ``Entity``)::

    @ros2_lv/<domain>/<zid>/<node id>/<entity id>/<NN|MP|MS>/<enclave>/<namespace>/<node>
        [/<topic>/<DDS type name>/<type hash>/<QoS>]   (publishers and subscriptions)

where ``<zid>`` is the zenoh session id, names have each ``/`` replaced by ``%`` (so ``/`` is
``%``), and ``<QoS>`` lists reliability, durability, ``history,depth``, deadline, lifespan and
liveliness separated by ``:``, each field left empty when it is rmw_zenoh's default (reliable,
volatile, keep-last 42, infinite durations, automatic liveliness).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from ubitrack_agent.io.ros2.keys import check_domain_id, dds_type_name

ADMIN_SPACE = "@ros2_lv"
NODE, PUBLISHER, SUBSCRIPTION = "NN", "MP", "MS"

_RELIABLE, _BEST_EFFORT = 1, 2  # rmw's enum values (rmw/types.h)
_TRANSIENT_LOCAL, _VOLATILE = 1, 2
_KEEP_LAST = 1
_DEFAULT_DEPTH = 42

NODE_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
"""A ROS node name (rcl's rule: letters, digits and underscores, not starting with a digit)."""


@dataclass(frozen=True)
class QoS:
    """The QoS a tf endpoint declares: tf2's profiles are reliable keep-last; /tf_static is
    transient-local with depth 1 (``tf2_ros::StaticBroadcasterQoS``), /tf volatile with depth
    100 (``DynamicBroadcasterQoS``)."""

    transient_local: bool = False
    depth: int = 100
    reliable: bool = True

    def keyexpr(self) -> str:
        reliability = "" if self.reliable else str(_BEST_EFFORT)
        durability = str(_TRANSIENT_LOCAL) if self.transient_local else ""
        depth = "" if self.depth == _DEFAULT_DEPTH else str(self.depth)
        return f"{reliability}:{durability}:,{depth}:,:,:,,"


TF_QOS = QoS(transient_local=False, depth=100)
TF_STATIC_QOS = QoS(transient_local=True, depth=1)


def mangle(name: str) -> str:
    """A ROS name as one key chunk: each ``/`` becomes ``%``."""
    return name.replace("/", "%")


@dataclass(frozen=True)
class NodeIdentity:
    """Who the bridge is in the ROS graph: a node ``name`` in ``namespace`` of one zenoh
    session (``zid``) on ROS domain ``domain_id``."""

    domain_id: int
    zid: str
    name: str
    namespace: str = "/"
    node_id: int = 0
    enclave: str = "/"

    def __post_init__(self) -> None:
        check_domain_id(self.domain_id)
        if not NODE_NAME.match(self.name):
            raise ValueError(f"ROS node name {self.name!r}: letters, digits and _ only")
        if not self.namespace.startswith("/"):
            raise ValueError(f"ROS namespace {self.namespace!r} must start with /")

    def _prefix(self, entity_id: int, kind: str) -> str:
        return "/".join(
            (
                ADMIN_SPACE,
                str(self.domain_id),
                self.zid,
                str(self.node_id),
                str(entity_id),
                kind,
                mangle(self.enclave),
                mangle(self.namespace),
                mangle(self.name),
            )
        )

    def node_token(self) -> str:
        """The node's token (entity id = node id, as rmw_zenoh does)."""
        return self._prefix(self.node_id, NODE)

    def endpoint_token(
        self, entity_id: int, kind: str, topic: str, typename: str, type_hash: str, qos: QoS
    ) -> str:
        """A publisher's (``MP``) or subscription's (``MS``) token for ``topic``."""
        if kind not in (PUBLISHER, SUBSCRIPTION):
            raise ValueError(f"endpoint kind {kind!r} is not {PUBLISHER} or {SUBSCRIPTION}")
        return "/".join(
            (
                self._prefix(entity_id, kind),
                mangle(topic),
                mangle(dds_type_name(typename)),
                mangle(type_hash),
                qos.keyexpr(),
            )
        )
