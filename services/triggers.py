"""Trigger timestamps that wait briefly for the other inputs to catch up.

Interpolating an input at a trigger's time ``t`` needs a sample of that input at or after
``t``. Samples of one instant travel separately (a camera publishes each feature's 2D edge on
its own key), so a trigger is held until every dynamic input has a sample at or after ``t``,
or until ``wait`` seconds have passed; then it is evaluated (nearest sample within the
tolerance window where there is nothing to interpolate). Every dynamic binding may trigger:
an instant is computed once, and a trigger older than the last instant computed is stale.
"""

from __future__ import annotations

from collections.abc import Callable


class PendingTriggers:
    """Trigger timestamps (ns) with their deadlines (monotonic seconds), oldest first."""

    def __init__(self, wait_s: float) -> None:
        self.wait_s = wait_s
        self.last_done: int | None = None
        self._deadlines: dict[int, float] = {}

    def __len__(self) -> int:
        return len(self._deadlines)

    def add(self, timestamp_ns: int, now: float) -> bool:
        """Hold a trigger; False if that instant is pending, done, or older than the last done."""
        if (self.last_done is not None and timestamp_ns <= self.last_done) or (
            timestamp_ns in self._deadlines
        ):
            return False
        self._deadlines[timestamp_ns] = now + self.wait_s
        return True

    def due(self, now: float, caught_up: Callable[[int], bool]) -> list[int]:
        """Remove and return, oldest first, the triggers whose inputs caught up or whose wait
        is over; stops at the first that must still wait, so instants stay in order."""
        ready = []
        for timestamp_ns in sorted(self._deadlines):
            if not (caught_up(timestamp_ns) or now >= self._deadlines[timestamp_ns]):
                break
            del self._deadlines[timestamp_ns]
            ready.append(timestamp_ns)
            self.last_done = timestamp_ns
        return ready

    def next_deadline(self) -> float | None:
        return min(self._deadlines.values()) if self._deadlines else None

    def clear(self) -> None:
        self._deadlines.clear()
