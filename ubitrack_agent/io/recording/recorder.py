"""Filling a :class:`~.writer.RecordingWriter` from zenoh: what the providers announce and
publish, as the agent learns it (``docs/protocol.md``).

The recorder watches the providers' liveliness tokens (with their history, so the providers
already running are recorded too); for each provider that appears it fetches its fragment,
records the announcement, subscribes to each of its edges' data keys and, for static and pull
edges, fetches the latest value (a calibration database publishes its static edges once, long
before the recording started). When a token goes it records the withdrawal and unsubscribes.
Everything from the network is checked before it is written: a fragment by
:func:`~.fragments.parse_fragment`, a measurement by ``core.codec.decode``; a rejected one is
logged (rate-limited) and counted in :attr:`Recorder.counters`, never fatal. Token events are
handled on one thread of the recorder's own, samples on each edge's input thread
(``net.transport.subscribe_in_bursts``). O(1) per sample; O(edges) subscriptions.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections import Counter
from collections.abc import Callable, Set
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
        ``internal_errors``."""
        self._subscribers: dict[str, list[Any]] = {}
        self._seen: set[str] = set()
        """Edge ids with a sample recorded."""
        self._stop = threading.Event()
        self._events: queue.SimpleQueue[tuple[bool, str] | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, daemon=True, name="recorder")
        self._thread.start()
        self._watch = session.liveliness().declare_subscriber(
            keys.all_providers(),
            lambda sample: self._events.put(
                (sample.kind == zenoh.SampleKind.PUT, str(sample.key_expr))
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
        while (event := self._events.get()) is not None:
            handle(*event)

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
            deliver = logs.guarded(
                lambda burst, name=edge.name: self._samples(provider, name, burst),
                self.counters,
                log,
                key,
            )
            subscribers.append(subscribe_in_bursts(self._session, key, deliver))
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
        """Stop watching and unsubscribe (the caller then finishes the writer)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        self._watch.undeclare()
        self._events.put(None)
        self._thread.join(timeout=5.0)
        for provider in list(self._subscribers):
            self._unsubscribe(provider)
