"""Sequence numbers on the data path, so that a sample zenoh dropped is counted, not lost
silently.

Zenoh drops a sample put with congestion control DROP when a link's transmission queue stays
full (its ``wait_before_drop``: ``net.config.DROP_WAIT_US``, 10 ms; then every droppable
message on that queue until a batch frees: ``push_network_message`` in zenoh's
``io/zenoh-transport/src/common/pipeline.rs``), and tells neither the sender nor the reader;
zenoh-python has no drop counter. Every put of the data path drops (``net.transport``,
"Nothing waits for a reader").
So each :class:`~ubitrack_agent.net.transport.LatestValuePublisher` numbers its puts
(:class:`Numbering`) in the sample's attachment (zenoh's, stable in 1.x: the payload and its
codec are unchanged), and a reader (a worker's input, an application's relation) counts the
numbers it never saw (:class:`Gaps`): the samples lost between that publisher and that reader,
wherever on the way (``docs/performance.md``, "Which puts may wait (session 24)" and "A stalled
reader holds nobody (session 27)").

A number belongs to one publisher (an id drawn when it is declared): two producers on one key
(a hand-over, make before break: ``services.handover``) are counted apart, and a publisher
declared again (a rewire, a restart) starts a new count, not a gap. A reader's first sample of
a publisher is no gap (it may have started later). Growth: O(1) time per sample, O(1) memory
per publisher; a reader keeps the last number of at most :data:`MAX_SOURCES` publishers.
"""

from __future__ import annotations

import os
import threading

ID_BYTES = 8
"""Bytes of a publisher's id: random, so ids of publishers in different processes differ."""
NUMBER_BYTES = 8
ATTACHMENT_BYTES = ID_BYTES + NUMBER_BYTES
MAX_SOURCES = 16
"""Publishers a reader remembers at once (a key has one producer, two during a hand-over, a
few more after rewires); the one heard from least recently is forgotten first."""


class Numbering:
    """The attachments of one publisher's puts: its id, then the put's number (from 0)."""

    def __init__(self) -> None:
        self._id = os.urandom(ID_BYTES)
        self._next = 0

    def next(self) -> bytes:
        """The attachment of the next put (call once per put, under the publisher's own order)."""
        number = self._next
        self._next = number + 1
        return self._id + number.to_bytes(NUMBER_BYTES, "little")


class Gaps:
    """Samples missed by the readers of one holder (a worker's inputs, an application's
    relation): the total, read from any thread, and one :class:`Numbers` per subscription."""

    def __init__(self) -> None:
        self.missed = 0
        """Samples never received: numbers skipped between two samples of one publisher."""
        self._lock = threading.Lock()

    def reader(self) -> Numbers:
        """The numbers of one subscription, counting its gaps here."""
        return Numbers(self)

    def add(self, gap: int) -> None:
        with self._lock:  # readers' threads add at once (only on a gap: rare)
            self.missed += gap


class Numbers:
    """The last number of each publisher one subscription heard from; called by the one thread
    taking that subscription's samples."""

    def __init__(self, gaps: Gaps) -> None:
        self._gaps = gaps
        self._last: dict[bytes, int] = {}

    def seen(self, attachment: bytes | None) -> int:
        """Note a sample's attachment; the samples missed right before it, also added to the
        holder's :class:`Gaps` (0 for a sample without a number, a publisher's first, or one
        not after its last)."""
        if attachment is None or len(attachment) != ATTACHMENT_BYTES:
            return 0  # not numbered (a test's put, a foreign publisher): nothing to count
        source, number = attachment[:ID_BYTES], int.from_bytes(attachment[ID_BYTES:], "little")
        last = self._last.pop(source, None)  # inserted again below: the most recent comes last
        if last is not None and number <= last:
            self._last[source] = last
            return 0
        self._last[source] = number
        if len(self._last) > MAX_SOURCES:
            del self._last[next(iter(self._last))]
        if last is None or number == last + 1:
            return 0
        gap = number - last - 1
        self._gaps.add(gap)
        return gap
