"""Filling a :class:`~.writer.RecordingWriter` from zenoh: what the providers announce and
publish, as the agent learns it (``docs/protocol.md``).

The recorder watches the providers' liveliness tokens (with their history, so the providers
already running are recorded too); for each provider that appears it fetches its fragment,
records the announcement, subscribes to each of its edges' data keys and, for static and pull
edges, fetches the latest value (a calibration database publishes its static edges once, long
before the recording started). When a token goes it records the withdrawal and unsubscribes.
Everything from the network is checked before it is written: a fragment by
:func:`~.fragments.parse_fragment`, a measurement by ``core.codec.decode``; a rejected one is
logged (rate-limited) and counted in :attr:`Recorder.counters`, never fatal.

Nothing is lost while memory lasts: each edge's input thread (``net.transport.subscribe_in_bursts``)
only queues the payloads it takes from zenoh, and one thread of the recorder's own checks and
writes them, in the order they came, with the token events (so a withdrawal is written after
the samples that came before it). A recorder slower than its providers (about 5,000 samples
a second here, ``docs/performance.md``) lets the queue grow instead of letting zenoh's queues
fill, which drop what they cannot take; past :data:`MAX_BACKLOG` samples waiting, new ones
are dropped and counted (``dropped_backlog``). :meth:`Recorder.close` writes everything that
came before it. O(1) per sample; O(edges) subscriptions; memory O(backlog).
"""

from __future__ import annotations

import logging
import queue
import threading
from collections import Counter
from collections.abc import Callable, Set
from dataclasses import dataclass
from typing import Any

import zenoh

from ubitrack_agent.core import MeasurementError, decode
from ubitrack_agent.io.recording.fragments import Announced, parse_fragment
from ubitrack_agent.io.recording.layout import RecordingError
from ubitrack_agent.io.recording.writer import RecordingWriter
from ubitrack_agent.net import logs
from ubitrack_agent.net.json_messages import MessageError, load_object
from ubitrack_agent.net.keys import KeyRejection, KeySpace
from ubitrack_agent.net.lifecycle import Closing
from ubitrack_agent.net.transport import fetch_latest, subscribe_in_bursts

log = logging.getLogger("ubitrack.record")

MAX_FRAGMENT_BYTES = 1 << 20
CHANNEL_CAPACITY = 65_536
"""Samples zenoh queues per edge for the recorder's input thread (``subscribe_in_bursts``): room
for a burst while that thread waits for Python's lock or a CPU on a loaded machine."""
MAX_BACKLOG = 1_000_000
"""Samples waiting to be written before new ones are dropped (about 200 MB of 6D samples
with covariance: 76 bytes each in the file, about 200 in memory)."""
FRAGMENT_RETRY_S = (0.0, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0)
"""Pauses between attempts to fetch a new provider's fragment (its queryable may come up a
moment after its token reaches us)."""


class Recorder(Closing):
    """Records the providers of ``keys``' domain (only those named in ``providers``, if given)
    into ``writer``; ``changed(provider, announced or None)`` is told of each announcement and
    withdrawal (on the recorder's thread)."""

    def __init__(
        self,
        session: Any,
        keys: KeySpace,
        writer: RecordingWriter,
        providers: Set[str] = frozenset(),
        changed: Callable[[str, Announced | None], None] = lambda provider, announced: None,
    ) -> None:
        self._session, self._keys, self._writer = session, keys, writer
        self._only, self._changed = frozenset(providers), changed
        self.counters: Counter[str] = Counter()
        """``rejected_fragments``, ``rejected_samples``, ``rejected_provider_keys``,
        ``internal_errors``, ``dropped_backlog`` (samples dropped with :data:`MAX_BACKLOG`
        waiting)."""
        self._subscribers: dict[str, list[Any]] = {}
        self._seen: set[str] = set()
        """Edge ids with a sample recorded."""
        self._stop = threading.Event()
        self._work: queue.SimpleQueue[_Token | _Burst | None] = queue.SimpleQueue()
        """Token events and sample bursts in the order they came; ``None`` ends the thread."""
        self._backlog = 0
        """Samples queued and not yet written (changed under :attr:`_backlog_lock`)."""
        self._backlog_lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, daemon=True, name="recorder")
        self._thread.start()
        self._watch = session.liveliness().declare_subscriber(
            keys.all_providers(),
            lambda sample: self._work.put(
                _Token(sample.kind == zenoh.SampleKind.PUT, str(sample.key_expr))
            ),
            history=True,
        )
        self._closed = False

    @property
    def providers(self) -> list[str]:
        """The providers being recorded now."""
        return sorted(self._subscribers)

    def _run(self) -> None:
        handle = logs.guarded(self._handle, self.counters, log, "provider tokens")
        while (item := self._work.get()) is not None:
            if isinstance(item, _Token):
                if not self._stop.is_set():
                    handle(item.appeared, item.key)
                continue
            with self._backlog_lock:
                self._backlog -= len(item.payloads)
            item.write(item.payloads)
        for provider in list(self._subscribers):
            self._unsubscribe(provider)

    def _queue(self, write: Callable[[list[bytes]], None], payloads: list[bytes]) -> None:
        """On an input thread: queue a burst for :meth:`_run`, or drop it (counted) if the
        backlog is full or the recording is closing."""
        if self._stop.is_set():
            return  # came after the recording's end
        with self._backlog_lock:
            full = self._backlog + len(payloads) > MAX_BACKLOG
            if not full:
                self._backlog += len(payloads)
        if full:
            logs.count_problem(
                self.counters,
                "dropped_backlog",
                log,
                "dropped %d samples: %d wait to be written already",
                len(payloads),
                MAX_BACKLOG,
            )
            return
        self._work.put(_Burst(write, payloads))

    @property
    def backlog(self) -> int:
        """Samples received and not yet written."""
        return self._backlog

    def _handle(self, appeared: bool, key: str) -> None:
        token = self._keys.parse_token("provider", key)
        if isinstance(token, KeyRejection):
            logs.count_problem(
                self.counters,
                token.counter,
                log,
                "ignored provider key %r: %s",
                token.key,
                token.reason,
            )
            return
        provider = token.name
        if self._only and provider not in self._only:
            return
        self._unsubscribe(provider)
        if not appeared:
            self._writer.withdrawn(provider)
            self._changed(provider, None)
            return
        announced = self._fragment(provider)
        if announced is None:
            return
        self._writer.announced(announced)
        subscribers = []
        for edge in announced.edges:
            key = self._keys.measured(provider, edge.name)
            write = logs.guarded(
                lambda burst, name=edge.name: self._samples(provider, name, burst),
                self.counters,
                log,
                key,
            )
            subscribers.append(
                subscribe_in_bursts(
                    self._session,
                    key,
                    lambda burst, write=write: self._queue(write, burst),
                    CHANNEL_CAPACITY,
                )
            )
        self._subscribers[provider] = subscribers
        for edge in announced.edges:
            if (edge.static or edge.mode == "pull") and f"{provider}/{edge.name}" not in self._seen:
                key = self._keys.measured(provider, edge.name)
                self._samples(provider, edge.name, fetch_latest(self._session, key))
        self._changed(provider, announced)

    def _fragment(self, provider: str) -> Announced | None:
        """The provider's announcement, fetched and checked; ``None`` (counted) if it has none
        or a malformed one."""
        payloads: list[bytes] = []
        for pause in FRAGMENT_RETRY_S:
            if self._stop.wait(pause):
                return None
            payloads = fetch_latest(self._session, self._keys.fragment(provider), timeout=1.0)
            if payloads:
                break
        if not payloads:
            logs.count_problem(
                self.counters, "rejected_fragments", log, "provider %r served no fragment", provider
            )
            return None
        try:
            return parse_fragment(load_object(payloads[0], MAX_FRAGMENT_BYTES), provider)
        except (MessageError, RecordingError) as exc:
            logs.count_problem(
                self.counters, "rejected_fragments", log, "provider %r: %s", provider, exc
            )
            return None

    def _samples(self, provider: str, edge_name: str, payloads: list[bytes]) -> None:
        for payload in payloads:
            try:
                value = decode(payload)
            except MeasurementError as exc:
                logs.count_problem(
                    self.counters,
                    "rejected_samples",
                    log,
                    "%s/%s: rejected sample: %s",
                    provider,
                    edge_name,
                    exc,
                )
                continue
            if self._writer.measured(provider, edge_name, payload, value):
                self._seen.add(f"{provider}/{edge_name}")

    def _unsubscribe(self, provider: str) -> None:
        for subscriber in self._subscribers.pop(provider, []):
            subscriber.undeclare()

    def close(self) -> None:
        """Stop watching, write every sample that came before, unsubscribe (the caller then
        finishes the writer). Takes as long as the backlog takes to write (at most
        :data:`MAX_BACKLOG` samples)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        self._watch.undeclare()
        self._work.put(None)
        self._thread.join()


@dataclass(frozen=True)
class _Token:
    """A provider's token appeared (or went) on ``key``."""

    appeared: bool
    key: str


@dataclass(frozen=True)
class _Burst:
    """Payloads taken from one edge's data key, to ``write``."""

    write: Callable[[list[bytes]], None]
    payloads: list[bytes]
