"""Data liveness: a measured edge whose provider is alive but whose data stopped counts as gone.

A provider's token says the process lives, not that its edges deliver: when ``ubitrack sim art``
dies while its DTrack adapter lives, the adapter still announces the A.R.T. edges. So the agent
watches the arrival of samples on the data key of every *watched* edge: a dynamic push edge
announcing a rate. Such an edge is *stale* when no sample arrived for
``max(STALE_PERIODS / rate, STALE_MIN_S)`` seconds (20 periods, at least 1 s: 1 s at 60 Hz, 20 s
at 1 Hz); the agent then plans without it until a sample arrives again. Static edges, pull edges
and edges without a rate are never stale. A newly watched edge counts from the moment it is
watched, so a provider has the same time to deliver its first sample.

Silence counts only while the agent itself runs: when its checks pause for longer than
``PAUSE_S`` (the agent starved of CPU on an overloaded machine, or stopped in a debugger), the
pause is not held against any edge, and the samples queued meanwhile get the time to arrive.
Without this, an agent that did not run for a second found every edge stale at once and
stopped every worker (seen with four test suites on two vCPUs).

Only arrival times are kept: the callback on zenoh's thread stores one number per sample and
never reads the payload. Everything else runs on the agent's thread.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

STALE_PERIODS = 20.0
"""Periods of its announced rate without a sample after which an edge counts as gone."""
STALE_MIN_S = 1.0
"""Shortest silence after which an edge counts as gone, whatever its rate."""
PAUSE_S = 0.25
"""A longer time between two checks is a pause of the agent, not silence of the edges (the
agent checks at least every 50 ms)."""


def stale_after(entry: Mapping[str, Any]) -> float | None:
    """Seconds without a sample after which the announced edge ``entry`` (a setup-file entry
    of ``announcements.fragment_entries``) counts as gone; ``None`` if it is never stale
    (static, pull, or no rate)."""
    rate = float(entry.get("rate", 0.0))
    if entry.get("static", False) or entry.get("mode", "push") != "push" or rate <= 0:
        return None
    return max(STALE_PERIODS / rate, STALE_MIN_S)


class DataLiveness:
    """The arrival time of the last sample of each watched edge, and which ones are stale."""

    def __init__(self) -> None:
        self.windows: dict[str, float] = {}
        self._last: dict[str, float] = {}
        self._checked: float | None = None

    def watch(self, entries: Iterable[Mapping[str, Any]], now: float) -> tuple[set[str], set[str]]:
        """Watch exactly the watchable edges among ``entries`` (the live SRG's); returns the
        edge ids newly watched and those no longer watched."""
        windows = {e["id"]: w for e in entries if (w := stale_after(e)) is not None}
        added, removed = set(windows) - set(self.windows), set(self.windows) - set(windows)
        for edge_id in added:
            self._last[edge_id] = now
        for edge_id in removed:
            self._last.pop(edge_id, None)
        self.windows = windows
        return added, removed

    def arrived(self, edge_id: str, now: float) -> None:
        """A sample of ``edge_id`` arrived (called on zenoh's thread: one assignment)."""
        self._last[edge_id] = now

    def stale(self, now: float) -> frozenset[str]:
        """The watched edges whose last sample is older than their window, not counting a
        pause of the checks (module docstring)."""
        if self._checked is not None and now - self._checked > PAUSE_S:
            paused = now - self._checked
            for edge_id, last in list(self._last.items()):
                self._last[edge_id] = min(last + paused, now)
        self._checked = now
        return frozenset(
            edge_id
            for edge_id, window in self.windows.items()
            if now - self._last.get(edge_id, now) > window
        )
