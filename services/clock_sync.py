"""A host manager's estimate of its host's clock offset to the active agent's, kept current.

As soon as an agent answers on ``<root>/agent/clock`` and then every :data:`REFRESH_S`, it
makes :data:`~ubitrack_agent.net.clock.DEFAULT_EXCHANGES` NTP-style exchanges and keeps the
one with the smallest round trip (:func:`ubitrack_agent.net.clock.measure_offset`: RFC 5905,
Cristian 1989); until an agent answers it asks every :data:`RETRY_S`. The latest estimate is
the ``clock`` entry of the host manager's status (``docs/protocol.md``, "Clocks"), with its
age; the agent reads it to correct the timestamps of inputs from hosts whose clocks differ.
A failed attempt keeps the previous estimate, whose age then says how old it is.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from typing import Any

from ubitrack_agent.net import logs
from ubitrack_agent.net.clock import Clock, ClockEstimate, measure_offset
from ubitrack_agent.net.keys import KeySpace

log = logging.getLogger("ubitrack.host")

REFRESH_S = 10.0
"""Seconds between two estimates once an agent has answered."""
RETRY_S = 0.5
"""Seconds between two attempts while no agent answers."""


class ClockSync:
    """Estimates ``clock``'s offset to the agent's on ``session`` in a thread of its own,
    between :meth:`start` and :meth:`stop`, counting into ``counters`` (``clock_estimates``
    and those of :func:`~ubitrack_agent.net.clock.measure_offset`)."""

    def __init__(self, session: Any, keys: KeySpace, clock: Clock, counters: Counter[str]) -> None:
        self._session, self._key, self.clock = session, keys.agent_clock(), clock
        self.counters = counters
        self._latest: tuple[ClockEstimate, float] | None = None
        """The latest estimate and when it was made (monotonic seconds)."""
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True, name="clock-sync")

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        """End the estimates (waits for an exchange under way, at most a second)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=1.0)

    def _run(self) -> None:
        estimate = logs.guarded(self._estimate, self.counters, log, "clock estimate")
        while not self._stop.is_set():
            before = self._latest
            estimate()
            self._stop.wait(REFRESH_S if self._latest is not before else RETRY_S)

    def _estimate(self) -> None:
        estimate = measure_offset(self._session, self._key, self.clock, self.counters)
        if estimate is not None:
            self._latest = (estimate, time.monotonic())
            self.counters["clock_estimates"] += 1

    def status(self) -> dict[str, Any] | None:
        """The status entry ``clock``: the latest estimate with its age, or None before the
        first (safe from any thread)."""
        latest = self._latest
        if latest is None:
            return None
        estimate, made = latest
        return estimate.as_status(time.monotonic() - made)
