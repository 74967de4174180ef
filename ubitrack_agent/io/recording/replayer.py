"""Announcing and publishing a recording's providers again, so the agent plans and calibrates
on it as on the live system.

:class:`Replayer` takes the events of :func:`~.reader.read_recording` in order. An announcement
opens a :class:`~ubitrack_agent.io.provider.Provider` with the recorded id and edges (on this
machine's host name: the workers are placed near the replay), a withdrawal closes it, and a
sample is published by its provider. Pacing keeps the recording's spacing: the event the
recorder received at ``log_time`` is handed on at ``start + (log_time - first log_time) /
speed``. Measurement timestamps keep their recorded spacing too; with ``shift`` (the default
of ``ubitrack replay``) each is moved by one constant, ``replay start (wall clock) - first
log_time``, so at ``speed`` 1 every sample is as old when published as it was when recorded;
without it they are published as recorded. At another speed the shifted timestamps drift from
the wall clock by ``(1 - 1/speed)`` of the recording time played (consumers refuse samples more
than ``core.measurements.MAX_FUTURE_NS`` ahead of their clock). Each pass (``--loop``) computes
its own shift, so timestamps keep increasing from pass to pass.

Lateness, how long after its due time each sample was published, is kept in
:attr:`Replayer.lateness_ns` when ``measure`` is set (``bench/recording_bench.py``). O(1) per
event; O(providers) memory.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from collections.abc import Iterable
from typing import Any

from ubitrack_agent.core import MeasurementError
from ubitrack_agent.io.provider import Provider
from ubitrack_agent.io.recording.fragments import Announced
from ubitrack_agent.io.recording.reader import Announcement, Event, Sample, Withdrawal
from ubitrack_agent.net import logs
from ubitrack_agent.net.keys import KeyRejection, KeySpace
from ubitrack_agent.net.lifecycle import Closing

log = logging.getLogger("ubitrack.replay")

MAX_WAIT_S = 3600.0
"""Longest single wait of the pacing (see :meth:`Replayer._wait_until`)."""


def live_providers(session: Any, keys: KeySpace, timeout: float = 1.0) -> set[str]:
    """The providers whose liveliness tokens are on ``keys``' domain now (a replay of one of
    them would make two providers of one id)."""
    found = set()
    for reply in session.liveliness().get(keys.all_providers(), timeout=timeout):
        if reply.ok is not None:
            token = keys.parse_token("provider", str(reply.ok.key_expr))
            if not isinstance(token, KeyRejection):
                found.add(token.name)
    return found


class Replayer(Closing):
    """Replays recordings into ``keys``' domain as providers running on ``host``; ``stop``
    ends a pass early."""

    def __init__(
        self,
        session: Any,
        keys: KeySpace,
        host: str,
        speed: float = 1.0,
        shift: bool = True,
        stop: threading.Event | None = None,
        measure: bool = False,
    ) -> None:
        if not speed > 0:
            raise ValueError(f"speed must be > 0, got {speed}")
        self._session, self._keys, self._host = session, keys, host
        self.speed, self.shift = speed, shift
        self._stop = stop or threading.Event()
        self._open: dict[str, tuple[Announced, Provider]] = {}
        self.counters: Counter[str] = Counter()
        """``announced``, ``withdrawn``, ``published``, ``passes``, and ``unplayable`` (a
        sample whose shifted timestamp is no timestamp: logged, rate-limited)."""
        self.lateness_ns: list[int] | None = [] if measure else None
        self.offset_ns = 0
        """The shift of the timestamps in the current (or last) pass."""

    @property
    def providers(self) -> list[str]:
        """The providers announced now."""
        return sorted(self._open)

    def play(self, events: Iterable[Event]) -> bool:
        """Replay one pass of ``events``; False if ``stop`` ended it early."""
        first = start = offset = 0
        for index, event in enumerate(events):
            if index == 0:
                first, start = event.log_time_ns, time.monotonic_ns()
                offset = time.time_ns() - first if self.shift else 0
                self.offset_ns = offset
            due = start + round((event.log_time_ns - first) / self.speed)
            if not self._wait_until(due):
                return False
            self._apply(event, offset)
            if self.lateness_ns is not None and isinstance(event, Sample):
                self.lateness_ns.append(time.monotonic_ns() - due)
        self.counters["passes"] += 1
        return True

    def _wait_until(self, due_ns: int) -> bool:
        """Wait until ``due_ns`` (monotonic); False if ``stop`` came first. Waits in steps of
        at most ``MAX_WAIT_S``: a gap of years between two events (a file's log times are
        anyone's) is waited out, not an overflow of the platform's timeout."""
        while (wait := (due_ns - time.monotonic_ns()) / 1e9) > 0:
            if self._stop.wait(min(wait, MAX_WAIT_S)):
                return False
        return not self._stop.is_set()

    def _apply(self, event: Event, offset: int) -> None:
        if isinstance(event, Sample):
            opened = self._open.get(event.provider)
            if opened is None:
                return  # the reader yields no sample of a provider not announced
            measurement = event.measurement
            try:
                if offset:
                    measurement = measurement.restamped(measurement.timestamp_ns + offset)
            except MeasurementError as exc:
                logs.count_problem(self.counters, "unplayable", log, "%s: %s", event.provider, exc)
                return
            opened[1].publish(event.edge_name, measurement)
            self.counters["published"] += 1
        elif isinstance(event, Announcement):
            announced = event.announced
            current = self._open.get(announced.provider)
            if current is not None and current[0] == announced:
                return  # the same again (a loop's next pass)
            self._close(announced.provider)
            provider = Provider(
                self._session, self._keys, announced.provider, announced.edges, self._host
            )
            self._open[announced.provider] = (announced, provider)
            self.counters["announced"] += 1
        elif isinstance(event, Withdrawal):
            self._close(event.provider)
            self.counters["withdrawn"] += 1

    def _close(self, provider: str) -> None:
        opened = self._open.pop(provider, None)
        if opened is not None:
            opened[1].close()

    def close(self) -> None:
        """Withdraw every provider still announced."""
        for provider in list(self._open):
            self._close(provider)
