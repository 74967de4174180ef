"""Writing a recording (the package docstring's layout) with the ``mcap`` library.

:class:`RecordingWriter` is safe to call from several threads (one lock; zenoh's callbacks and
the recorder's thread write). A measurement channel and, for 6D and 3D edges, a
``foxglove.FrameTransform`` channel are registered the first time an edge is announced; MCAP
compresses chunks with zstd. :meth:`RecordingWriter.finish` writes the summary (statistics,
indexes) and the footer: without it the file is readable from the start (``ubitrack replay``
says where it ends) but not indexed. O(1) per message, O(edges) memory.
"""

from __future__ import annotations

import json
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import BinaryIO

from mcap.writer import CompressionType, Writer

from ubitrack_agent import __version__
from ubitrack_agent.core import Measurement
from ubitrack_agent.io.provider import EdgeAnnouncement
from ubitrack_agent.io.recording.fragments import Announced
from ubitrack_agent.io.recording.frame_transform import (
    TRANSFORM_TYPES,
    frame_transform,
    transform_schema,
)
from ubitrack_agent.io.recording.layout import (
    ANNOUNCEMENT_SCHEMA,
    ANNOUNCEMENT_SCHEMA_NAME,
    ANNOUNCEMENTS_TOPIC,
    FORMAT_VERSION,
    PROFILE,
    TRANSFORM_SCHEMA_NAME,
    data_topic,
    transform_topic,
)

_TRANSFORM_SRG_TYPES = frozenset(cls.SRG_TYPE for cls in TRANSFORM_TYPES)


class RecordingWriter:
    """Writes announcements and measurements to ``stream`` (opened for binary writing; the
    caller closes it after :meth:`finish`). ``clock`` gives the log time (Unix ns)."""

    def __init__(self, stream: BinaryIO, clock: Callable[[], int] = time.time_ns) -> None:
        self._clock = clock
        self._lock = threading.Lock()
        self._writer = Writer(stream, compression=CompressionType.ZSTD)
        self._writer.start(profile=PROFILE, library=f"ubitrack-agent {__version__}")
        schema = self._writer.register_schema(
            ANNOUNCEMENT_SCHEMA_NAME, "jsonschema", ANNOUNCEMENT_SCHEMA
        )
        self._announcements = self._writer.register_channel(
            ANNOUNCEMENTS_TOPIC, "json", schema, {"format_version": FORMAT_VERSION}
        )
        self._transform_schema = self._writer.register_schema(
            TRANSFORM_SCHEMA_NAME, "protobuf", transform_schema()
        )
        self._channels: dict[tuple[str, str], tuple[int, int | None]] = {}
        """(edge id, edge type) -> its measurement channel and frame transform channel."""
        self._live: dict[str, dict[str, EdgeAnnouncement]] = {}
        """The edges of each provider announced and not withdrawn, by name."""
        self.counters: Counter[str] = Counter()
        """``announcements``, ``withdrawals``, ``measurements``, ``transforms``, and
        ``not_announced`` (a sample of an edge no live provider announces, not written)."""
        self._finished = False

    def announced(self, announcement: Announced) -> None:
        """Record that a provider announced its fragment (again: it replaces the last)."""
        event = {"event": "announced", "provider": announcement.provider}
        with self._lock:
            for edge in announcement.edges:
                self._register(
                    announcement.provider, edge.name, edge.type, edge.source, edge.target
                )
            self._live[announcement.provider] = {e.name: e for e in announcement.edges}
            self._event({**event, "fragment": announcement.as_json()})
            self.counters["announcements"] += 1

    def withdrawn(self, provider: str) -> None:
        """Record that a provider's token went; nothing if it was not announced."""
        with self._lock:
            if self._live.pop(provider, None) is not None:
                self._event({"event": "withdrawn", "provider": provider})
                self.counters["withdrawals"] += 1

    def measured(self, provider: str, edge_name: str, payload: bytes, value: Measurement) -> bool:
        """Record one measurement: ``payload`` as it travelled, ``value`` decoded from it;
        False (counted, not written) if no live provider announces the edge with its type."""
        with self._lock:
            edge = self._live.get(provider, {}).get(edge_name)
            if self._finished or edge is None or edge.type != value.SRG_TYPE:
                self.counters["not_announced"] += 1
                return False
            data, transform = self._channels[f"{provider}/{edge_name}", edge.type]
            now = self._clock()
            self._writer.add_message(data, now, payload, value.timestamp_ns)
            self.counters["measurements"] += 1
            if transform is not None and (
                message := frame_transform(edge.source, edge.target, value)
            ):
                self._writer.add_message(transform, now, message, value.timestamp_ns)
                self.counters["transforms"] += 1
            return True

    def finish(self) -> None:
        """Write the summary and footer; later calls do nothing."""
        with self._lock:
            if not self._finished:
                self._finished = True
                self._writer.finish()

    def _register(self, provider: str, name: str, edge_type: str, source: str, target: str) -> None:
        edge_id = f"{provider}/{name}"
        if (edge_id, edge_type) in self._channels:
            return
        metadata = {
            "provider": provider,
            "edge": name,
            "type": edge_type,
            "from": source,
            "to": target,
            "format_version": FORMAT_VERSION,
        }
        data = self._writer.register_channel(data_topic(edge_id), "msgpack", 0, metadata)
        transform = None
        if edge_type in _TRANSFORM_SRG_TYPES:
            transform = self._writer.register_channel(
                transform_topic(edge_id), "protobuf", self._transform_schema, metadata
            )
        self._channels[edge_id, edge_type] = (data, transform)

    def _event(self, event: dict) -> None:
        payload = json.dumps(event, sort_keys=True).encode()
        now = self._clock()
        self._writer.add_message(self._announcements, now, payload, now)
