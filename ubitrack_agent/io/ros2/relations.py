"""Follow chosen SRG relations and publish them as tf (``ubitrack ros2 publish``).

Each relation is an application query (:class:`~ubitrack_agent.io.application.Relation`):
the agent plans it and its samples arrive here. A relation ``A -> B`` (the pose of B in A)
becomes the transform ``frame_id`` = A, ``child_frame_id`` = B, with the frames named by
:class:`~.frames.FrameNames`, stamped with the sample's measurement timestamp. Dynamic
relations go on /tf, static ones on /tf_static (:class:`~.publisher.TfPublisher`: the whole
static tree in one message, kept for late joiners).

The relations' callbacks run on zenoh's threads and only queue; :meth:`RelationsToTf.pump`
(the caller's thread) takes what is queued and puts every dynamic sample in one TFMessage, so
a burst costs one message. O(samples) per pump.
"""

from __future__ import annotations

import queue
import threading
import time
from collections import Counter
from collections.abc import Sequence
from typing import Any

from ubitrack_agent.core import Measurement
from ubitrack_agent.io.application import Relation
from ubitrack_agent.io.ros2.cdr import Transform
from ubitrack_agent.io.ros2.frames import FrameNameError, FrameNames
from ubitrack_agent.io.ros2.publisher import TfPublisher
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.lifecycle import Closing


def ros_frames(relations: Sequence[RelationId], frames: FrameNames) -> dict[str, str]:
    """The ROS frame id of every frame of ``relations``; :class:`FrameNameError` listing
    every refused name at once."""
    names: dict[str, str] = {}
    refused: list[str] = []
    for relation in relations:
        for frame in (relation.source, relation.target):
            try:
                names[frame] = frames.to_ros(frame)
            except FrameNameError as exc:
                refused.append(str(exc))
    if refused:
        raise FrameNameError("; ".join(dict.fromkeys(refused)))
    return names


def transform_of(relation: RelationId, sample: Measurement, names: dict[str, str]) -> Transform:
    """The tf transform of one 6D sample of ``relation``."""
    return Transform(
        names[relation.source],
        names[relation.target],
        sample.timestamp_ns,
        tuple(float(v) for v in sample.translation),  # type: ignore[attr-defined]
        tuple(float(v) for v in sample.rotation),  # type: ignore[attr-defined]
    )


class RelationsToTf(Closing):
    """Queries ``relations`` and publishes their samples through ``publisher``."""

    def __init__(
        self,
        session: Any,
        keys: KeySpace,
        relations: Sequence[RelationId],
        publisher: TfPublisher,
        frames: FrameNames | None = None,
        host: str | None = None,
    ) -> None:
        if not relations:
            raise ValueError("no relation to publish")
        for relation in relations:
            if relation.type != "6D":
                raise ValueError(f"{relation}: tf carries 6D poses only")
        self.names = ros_frames(relations, frames or FrameNames())
        self.publisher = publisher
        self.counters: Counter[str] = Counter()
        self._queue: queue.SimpleQueue[tuple[RelationId, Measurement]] = queue.SimpleQueue()
        self.relations = [
            Relation(
                session,
                keys,
                relation,
                callback=lambda sample, r=relation: self._queue.put((r, sample)),
                host=host,
            )
            for relation in relations
        ]

    def pump(self, timeout: float) -> int:
        """Publish what arrived, waiting up to ``timeout`` seconds for the first sample;
        returns the number of samples published."""
        try:
            batch = [self._queue.get(timeout=timeout)]
        except queue.Empty:
            return 0
        while True:
            try:
                batch.append(self._queue.get_nowait())
            except queue.Empty:
                break
        dynamic = [transform_of(r, s, self.names) for r, s in batch if not r.static]
        static = [transform_of(r, s, self.names) for r, s in batch if r.static]
        self.publisher.publish(dynamic)
        if static:
            self.publisher.publish_static(static)
        self.counters["dynamic"] += len(dynamic)
        self.counters["static"] += len(static)
        return len(batch)

    def run(self, stop: threading.Event, duration_s: float | None = None) -> None:
        """:meth:`pump` until ``stop`` is set or ``duration_s`` seconds have passed."""
        end = None if duration_s is None else time.monotonic() + duration_s
        while not stop.is_set() and (end is None or time.monotonic() < end):
            self.pump(timeout=0.1)

    def close(self) -> None:
        for relation in self.relations:
            relation.close()
