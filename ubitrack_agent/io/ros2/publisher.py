"""Publish transforms on /tf and /tf_static as a ROS 2 node speaking rmw_zenoh (Jazzy+).

What a tf2 ``TransformBroadcaster`` and ``StaticTransformBroadcaster`` do through rmw_zenoh
(``rmw_zenoh_cpp/src/detail/rmw_publisher_data.cpp``):

* **/tf** (volatile): each :meth:`TfPublisher.publish` is one TFMessage put on the topic's key
  (:mod:`.keys`) with the attachment (:mod:`.attachment`: sequence number from 1, source
  timestamp, the publisher's gid).
* **/tf_static** (transient-local, depth 1): a zenoh-ext ``AdvancedPublisher`` with a cache of
  one sample and publisher detection, as rmw_zenoh declares a transient-local publisher. The
  static transforms are kept per child frame (tf2's rule: one parent per child) and every
  change puts *all* of them in one message, which the cache keeps: a subscriber that joins
  later (rmw_zenoh's transient-local subscription is an ``AdvancedSubscriber`` detecting late
  publishers and querying their history) receives the whole static tree.
* **Discovery**: liveliness tokens for the node and both publishers (:mod:`.liveliness`).

The gid is 16 bytes hashed from the publisher's token (BLAKE2b here, XXH3 in rmw_zenoh:
a subscriber passes it on as the publisher's id and never recomputes it). O(transforms) per
message; the static set is O(static frames).
"""

from __future__ import annotations

import hashlib
import threading
import time
from collections import Counter
from collections.abc import Iterable
from typing import Any

from ubitrack_agent.io.ros2.attachment import GID_BYTES, Attachment, encode_attachment
from ubitrack_agent.io.ros2.cdr import Transform, encode_tf
from ubitrack_agent.io.ros2.keys import TF_STATIC_TOPIC, TF_TOPIC, TF_TYPE, TF_TYPE_HASH, topic_key
from ubitrack_agent.io.ros2.liveliness import (
    PUBLISHER,
    TF_QOS,
    TF_STATIC_QOS,
    NodeIdentity,
    QoS,
)
from ubitrack_agent.net.lifecycle import Closing

DEFAULT_NODE_NAME = "ubitrack_tf"
HEARTBEAT_S = 0.5
"""Sporadic heartbeat of the /tf_static publisher, as rmw_zenoh's reliable transient-local
publishers send (``SAMPLE_MISS_DETECTION_HEARTBEAT_PERIOD``)."""


def gid_of(token: str) -> bytes:
    """A 16-byte publisher gid derived from its liveliness token."""
    return hashlib.blake2b(token.encode(), digest_size=GID_BYTES).digest()


class _Endpoint:
    """One rmw_zenoh publisher: key, token, gid, sequence numbers."""

    def __init__(
        self, session: Any, node: NodeIdentity, entity_id: int, topic: str, qos: QoS
    ) -> None:
        self.key = topic_key(node.domain_id, topic)
        self.token_key = node.endpoint_token(
            entity_id, PUBLISHER, topic, TF_TYPE, TF_TYPE_HASH, qos
        )
        self.gid = gid_of(self.token_key)
        self.sequence = 0
        if qos.transient_local:
            import zenoh.ext

            self.publisher = zenoh.ext.declare_advanced_publisher(
                session,
                self.key,
                cache=zenoh.ext.CacheConfig(max_samples=qos.depth),
                sample_miss_detection=zenoh.ext.MissDetectionConfig(sporadic_heartbeat=HEARTBEAT_S),
                publisher_detection=True,
            )
        else:
            self.publisher = session.declare_publisher(self.key)
        self.token = session.liveliness().declare_token(self.token_key)

    def put(self, payload: bytes) -> None:
        self.sequence += 1
        attachment = Attachment(self.sequence, time.time_ns(), self.gid)
        self.publisher.put(payload, attachment=encode_attachment(attachment))

    def undeclare(self) -> None:
        self.token.undeclare()
        self.publisher.undeclare()


class TfPublisher(Closing):
    """A ROS 2 node publishing /tf and /tf_static (module docstring). Thread-safe; a context
    manager (leaving the block undeclares everything)."""

    def __init__(
        self,
        session: Any,
        domain_id: int = 0,
        node_name: str = DEFAULT_NODE_NAME,
        namespace: str = "/",
    ) -> None:
        self.node = NodeIdentity(domain_id, str(session.info.zid()), node_name, namespace)
        self._node_token = session.liveliness().declare_token(self.node.node_token())
        self._tf = _Endpoint(session, self.node, 1, TF_TOPIC, TF_QOS)
        self._static = _Endpoint(session, self.node, 2, TF_STATIC_TOPIC, TF_STATIC_QOS)
        self.static_transforms: dict[str, Transform] = {}
        """The static tree published, by child frame."""
        self.counters: Counter[str] = Counter()
        self._lock = threading.Lock()
        self._closed = False

    @property
    def keys(self) -> tuple[str, str]:
        """The data keys of /tf and /tf_static."""
        return self._tf.key, self._static.key

    def publish(self, transforms: Iterable[Transform]) -> None:
        """Put ``transforms`` on /tf in one TFMessage."""
        batch = list(transforms)
        if not batch:
            return
        payload = encode_tf(batch)
        with self._lock:
            self._tf.put(payload)
            self.counters["tf_messages"] += 1
            self.counters["tf_transforms"] += len(batch)

    def publish_static(self, transforms: Iterable[Transform]) -> bool:
        """Add ``transforms`` to the static tree and, if it changed, put the whole tree on
        /tf_static in one TFMessage; returns whether it was put."""
        with self._lock:
            changed = False
            for transform in transforms:
                if self.static_transforms.get(transform.child) != transform:
                    self.static_transforms[transform.child] = transform
                    changed = True
            if changed:
                self._static.put(encode_tf(list(self.static_transforms.values())))
                self.counters["tf_static_messages"] += 1
            return changed

    def close(self) -> None:
        """Undeclare the tokens and publishers; a second call does nothing."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._tf.undeclare()
            self._static.undeclare()
            self._node_token.undeclare()
