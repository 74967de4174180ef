"""The one-line status long-running commands print periodically at the default log level
(``ubitrack agent``, ``host``, ``dtrack``, ``store`` and the ``sim`` simulators; ``ubitrack
camera`` has its own),
so a terminal shows that a process works and how fast without reading logs; ``--quiet`` turns
it off. Expected, frequent conditions are counted and appear here, not as one warning each.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from ubitrack_agent.core.lines import write_line

STATUS_EVERY_S = 10.0
"""Seconds between two status lines."""


class Rate:
    """Events per second of a growing count, between two calls of :meth:`per_second`."""

    def __init__(self, count: Callable[[], float]) -> None:
        self._count = count
        self._last = (time.monotonic(), count())

    def per_second(self) -> float:
        now, value = time.monotonic(), self._count()
        then, before = self._last
        self._last = (now, value)
        return (value - before) / max(now - then, 1e-9)


@contextmanager
def periodic_status(
    render: Callable[[], str],
    enabled: bool = True,
    every_s: float = STATUS_EVERY_S,
    show: Callable[[str], None] = write_line,
) -> Iterator[None]:
    """While the block runs, ``show(render())`` every ``every_s`` seconds on a thread of its
    own, and once more when the block ends; nothing if not ``enabled``. A failing ``render``
    shows the error instead of ending the thread."""
    if not enabled:
        yield
        return
    stop = threading.Event()

    def line() -> str:
        try:
            return render()
        except Exception as exc:  # a status line must never end the command
            return f"status unavailable: {type(exc).__name__}: {exc}"

    def loop() -> None:
        while not stop.wait(every_s):
            show(line())

    thread = threading.Thread(target=loop, daemon=True, name="status-line")
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(timeout=1.0)
        show(line())
