"""How long the agent's loop spends in each of its handlers: the longest pass and the slowest
handler of each window, shown in the status (``"loop"``), so a loop that holds up the agent's
answers can be seen, and which handler does it.

The agent's loop answers nothing itself (its status and answers are served from zenoh's
threads, from what the loop last published), but it shares Python's interpreter lock with
them: a pass that computes for long delays them by up to the interpreter's switch interval
per switch, and a C call that holds the lock throughout (``json.dumps`` of a large status)
delays them by all of it. O(1) per handler timed; O(handlers) per window.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any


class LoopTimes:
    """The loop's pass times and each handler's, over the window since :meth:`window`."""

    def __init__(self) -> None:
        self._handlers: dict[str, float] = {}
        self._slowest_pass = 0.0
        self._passes = 0
        self._window_started = time.perf_counter()
        self.last: dict[str, Any] = {}
        """The figures of the window last closed (:meth:`window`)."""

    @contextmanager
    def handler(self, name: str) -> Iterator[None]:
        """Time the block as the handler ``name`` (its longest run in the window is kept)."""
        started = time.perf_counter()
        try:
            yield
        finally:
            took = time.perf_counter() - started
            if took > self._handlers.get(name, 0.0):
                self._handlers[name] = took

    def pass_done(self, seconds: float) -> None:
        """One pass of the loop took ``seconds`` (its waits for events excluded)."""
        self._passes += 1
        self._slowest_pass = max(self._slowest_pass, seconds)

    def window(self) -> dict[str, Any]:
        """Close the window: its passes, longest pass, and the handler with the longest run
        (with that run), as :attr:`last`; a new window starts."""
        now = time.perf_counter()
        slowest = max(self._handlers.items(), key=lambda item: item[1], default=("", 0.0))
        self.last = {
            "window_s": now - self._window_started,
            "passes": self._passes,
            "slowest_pass_s": self._slowest_pass,
            "slowest_handler": slowest[0] or None,
            "slowest_handler_s": slowest[1],
        }
        self._handlers, self._slowest_pass, self._passes = {}, 0.0, 0
        self._window_started = now
        return self.last
