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

The attachment also names the key (``net.address``): a reader refuses a sample zenoh
delivered on another key than its publisher's (:meth:`Numbers.take` returns None), counted
``misaddressed`` in :class:`Gaps`.

A number belongs to one publisher (an id drawn when it is declared): two producers on one key
(a hand-over, make before break: ``services.handover``) are counted apart, and a publisher
declared again (a rewire, a restart) starts a new count, not a gap. A reader's first sample of
a publisher is no gap (it may have started later). Growth: O(1) time per sample, O(1) memory
per publisher; a reader keeps the last number of at most :data:`MAX_SOURCES` publishers.
"""

from __future__ import annotations

import os
import threading

from ubitrack_agent.net.address import NUMBERED_PREFIX_BYTES, TAG_BYTES, misaddressed, tag

ID_BYTES = 8
"""Bytes of a publisher's id: random, so ids of publishers in different processes differ."""
NUMBER_BYTES = NUMBERED_PREFIX_BYTES - ID_BYTES
"""Bytes of the put's number (unsigned, little-endian): the rest of what precedes the tag."""
ATTACHMENT_BYTES = NUMBERED_PREFIX_BYTES + TAG_BYTES
"""The publisher's id, the put's number, and the key's tag (``net.address``)."""
MAX_SOURCES = 16
"""Publishers a reader remembers at once (a key has one producer, two during a hand-over, a
few more after rewires); the one heard from least recently is forgotten first."""


class Numbering:
    """The attachments of one publisher's puts on ``key``: its id, the put's number (from 0),
    the key's tag."""

    def __init__(self, key: str) -> None:
        self._id = os.urandom(ID_BYTES)
        self._tag = tag(key)
        self._next = 0

    def next(self) -> bytes:
        """The attachment of the next put (call once per put, under the publisher's own order)."""
        number = self._next
        self._next = number + 1
        return self._id + number.to_bytes(NUMBER_BYTES, "little") + self._tag


class Gaps:
    """Samples missed by the readers of one holder (a worker's inputs, an application's
    relation): the total, read from any thread, and one :class:`Numbers` per subscription."""

    def __init__(self) -> None:
        self.missed = 0
        """Samples never received: numbers skipped between two samples of one publisher."""
        self.misaddressed = 0
        """Samples refused as put on another key (``net.address``)."""
        self._lock = threading.Lock()

    def reader(self, key: str | None) -> Numbers:
        """The numbers of one subscription to ``key`` (None: a wildcard, each sample's own key
        then told to :meth:`Numbers.take`), counting its gaps here."""
        return Numbers(self, key)

    def add(self, gap: int) -> None:
        with self._lock:  # readers' threads add at once (only on a gap: rare)
            self.missed += gap

    def refuse(self) -> None:
        with self._lock:
            self.misaddressed += 1


class Numbers:
    """The last number of each publisher one subscription heard from; called by the one thread
    taking that subscription's samples."""

    def __init__(self, gaps: Gaps, key: str | None) -> None:
        self._gaps = gaps
        self._tag = None if key is None else tag(key)
        self._last: dict[bytes, int] = {}

    def take(self, attachment: bytes | None, key: str | None = None) -> int | None:
        """Note a sample's attachment: None if it names another key than the subscription's
        (or, for a wildcard, than ``key``, the sample's), counted ``misaddressed``; else the
        samples missed right before it, also added to the holder's :class:`Gaps` (0 for a
        sample without a number, a publisher's first, or one not after its last)."""
        if attachment is None:
            return 0  # not ours (a test's put, a foreign publisher): nothing to tell
        key_tag = self._tag if key is None else tag(key)
        if len(attachment) != ATTACHMENT_BYTES:  # a command's, or not ours: not numbered
            if key_tag is not None and misaddressed(attachment, key_tag):
                self._gaps.refuse()
                return None
            return 0
        if key_tag is not None and attachment[NUMBERED_PREFIX_BYTES:] != key_tag:  # inline
            self._gaps.refuse()
            return None
        source = attachment[:ID_BYTES]
        number = int.from_bytes(attachment[ID_BYTES : ID_BYTES + NUMBER_BYTES], "little")
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
