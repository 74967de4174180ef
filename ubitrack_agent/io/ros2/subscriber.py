"""Receive /tf and /tf_static as a ROS 2 node speaking rmw_zenoh (Jazzy and later).

As rmw_zenoh subscribes (``rmw_zenoh_cpp/src/detail/rmw_subscription_data.cpp``): /tf with a
plain subscriber on the topic's key (:mod:`.keys`), /tf_static as a transient-local
subscription, a zenoh-ext ``AdvancedSubscriber`` that detects late publishers and queries
their cache (history, at most ``STATIC_HISTORY`` samples each) and follows their heartbeats,
so the static tree published before this process started still arrives. The node and its two
subscriptions declare liveliness tokens (:mod:`.liveliness`), so ``ros2 node list`` and
``ros2 topic info`` see them.

The zenoh callbacks only queue (:class:`TfSample`, stamped on arrival); a full queue drops the
sample and counts ``dropped_full``. Parsing happens on the reader's thread
(:mod:`.provider`). O(1) per sample here.
"""

from __future__ import annotations

import queue
from collections import Counter
from dataclasses import dataclass
from typing import Any

from ubitrack_agent.io.ros2.keys import TF_STATIC_TOPIC, TF_TOPIC, TF_TYPE, TF_TYPE_HASH, topic_key
from ubitrack_agent.io.ros2.liveliness import SUBSCRIPTION, NodeIdentity, QoS
from ubitrack_agent.net.clock import Clock
from ubitrack_agent.net.lifecycle import Closing

DEFAULT_NODE_NAME = "ubitrack_tf_listener"
STATIC_HISTORY = 100
"""History per late publisher, the depth of tf2's ``StaticListenerQoS``."""
QUEUE_SIZE = 4096
LISTENER_QOS = QoS(transient_local=False, depth=100)
STATIC_LISTENER_QOS = QoS(transient_local=True, depth=STATIC_HISTORY)


@dataclass(frozen=True)
class TfSample:
    """One sample as it arrived: which topic, its payload and attachment bytes (``None`` if it
    had none), and when (the process's clock, Unix ns)."""

    static: bool
    payload: bytes
    attachment: bytes | None
    received_ns: int


class TfSubscriber(Closing):
    """The two subscriptions of the module docstring; :meth:`get` takes the next sample."""

    def __init__(
        self,
        session: Any,
        domain_id: int = 0,
        node_name: str = DEFAULT_NODE_NAME,
        namespace: str = "/",
        clock: Clock | None = None,
        queue_size: int = QUEUE_SIZE,
    ) -> None:
        import zenoh.ext

        self.node = NodeIdentity(domain_id, str(session.info.zid()), node_name, namespace)
        self.counters: Counter[str] = Counter()
        self._clock = clock or Clock()
        self._queue: queue.Queue[TfSample] = queue.Queue(maxsize=queue_size)
        self.keys = (topic_key(domain_id, TF_TOPIC), topic_key(domain_id, TF_STATIC_TOPIC))
        self._tf = session.declare_subscriber(self.keys[0], lambda s: self._arrived(False, s))
        self._static = zenoh.ext.declare_advanced_subscriber(
            session,
            self.keys[1],
            lambda s: self._arrived(True, s),
            history=zenoh.ext.HistoryConfig(
                detect_late_publishers=True, max_samples=STATIC_HISTORY
            ),
            recovery=zenoh.ext.RecoveryConfig(heartbeat=True),
            subscriber_detection=True,
        )
        liveliness = session.liveliness()
        self._tokens = [
            liveliness.declare_token(self.node.node_token()),
            *(
                liveliness.declare_token(
                    self.node.endpoint_token(
                        entity_id, SUBSCRIPTION, topic, TF_TYPE, TF_TYPE_HASH, qos
                    )
                )
                for entity_id, topic, qos in (
                    (1, TF_TOPIC, LISTENER_QOS),
                    (2, TF_STATIC_TOPIC, STATIC_LISTENER_QOS),
                )
            ),
        ]
        self._closed = False

    def _arrived(self, static: bool, sample: Any) -> None:
        """Runs on zenoh's thread: copy out and queue, nothing else."""
        attachment = sample.attachment
        item = TfSample(
            static,
            sample.payload.to_bytes(),
            None if attachment is None else attachment.to_bytes(),
            self._clock.now_ns(),
        )
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            self.counters["dropped_full"] += 1

    def get(self, timeout: float) -> TfSample | None:
        """The next sample, or ``None`` if none arrives within ``timeout`` seconds."""
        try:
            return self._queue.get(timeout=timeout)
        except queue.Empty:
            return None

    def close(self) -> None:
        """Undeclare the tokens and subscriptions; a second call does nothing."""
        if self._closed:
            return
        self._closed = True
        for token in self._tokens:
            token.undeclare()
        self._tf.undeclare()
        self._static.undeclare()
