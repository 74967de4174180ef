"""Process plumbing shared by the simulators: tick at a fixed rate, run a provider on its own
zenoh session (stopping on signals: :mod:`ubitrack_agent.net.lifecycle`)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from ubitrack_agent.io.provider import EdgeAnnouncement, Provider
from ubitrack_agent.net.config import Settings
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.session import open_session


def run_periodic(
    rate_hz: float,
    step: Callable[[int], None],
    stop: threading.Event,
    duration_s: float | None = None,
) -> int:
    """Call ``step(time.time_ns())`` at ``rate_hz`` until ``stop`` is set or ``duration_s``
    has passed; returns the number of steps. Ticks are scheduled on absolute times, so the rate
    does not drift with the time each step takes (late ticks are not made up)."""
    period_ns = int(1e9 / rate_hz)
    start = next_tick = time.time_ns()
    end = None if duration_s is None else start + int(duration_s * 1e9)
    steps = 0
    while not stop.is_set():
        now = time.time_ns()
        if end is not None and now >= end:
            break
        step(now)
        steps += 1
        next_tick = max(next_tick + period_ns, time.time_ns() - period_ns)
        stop.wait(max(0.0, (next_tick - time.time_ns()) * 1e-9))
    return steps


@contextmanager
def provider_session(
    settings: Settings, provider_id: str, edges: list[EdgeAnnouncement]
) -> Iterator[Provider]:
    """A zenoh session with one :class:`~ubitrack_agent.io.provider.Provider` announced on it;
    both are closed on exit (the provider first, so the agent replans at once)."""
    with (
        open_session(settings) as session,
        Provider(
            session, KeySpace(settings.key_prefix), provider_id, edges, settings.host_name
        ) as provider,
    ):
        yield provider
