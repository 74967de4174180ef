"""Which of a provider's edges deliver now, judged where their samples are published.

A producer of a relation key that needs a measured edge (``services.handover``, rule 7) learns
that the edge stopped from a liveliness token on the edge's data key: the provider
(``io.provider``) declares it with the edge's first sample and withdraws it as soon as the edge
misses its samples, and its next sample declares it again. Judged here, at the adapter, the
silence is told from a sample on its way sooner than by the holder of the relation key, which
sees its own output's jitter on top of the sensor's (``docs/performance.md``, "An edge that
stops delivering"). An edge misses its samples when

* nothing was published for :data:`SILENT_INTERVALS` of its usual interval (the median of the
  intervals between its last :data:`INTERVALS_REMEMBERED` + 1 publications, worked out again
  every :data:`INTERVALS_REMEMBERED` samples, so a sample dropped now and then does not
  lengthen it), and at least :data:`LATE_MIN_S` beyond one
  usual interval (a sensor at kilohertz rates is not stopped by the scheduler's jitter); an
  edge whose rate is not known yet (fewer than :data:`INTERVALS_NEEDED` intervals seen) is
  never judged silent;
* or the adapter says so (:meth:`FlowingEdges.missed`): :data:`MISSED_IN_ROW` frames of its
  tracker in a row came without the edge's body (hidden, or the tracker lost it), which it
  knows as each frame arrives, with no margin for jitter.

One dropped frame (a simulated A.R.T. tracker drops 2 % of a body's) stops no edge: two
intervals between samples are half an interval short of the silence, and one frame left out
is not two. Stopping it would hand a relation key to another flow and back within a frame,
two token changes and four hand-over messages for nothing.

Times are passed in (monotonic seconds), so the rules are pure and tested without a clock. The
provider holds its lock around every call. Cost: O(1) a publication (a time appended), and
O(log edges) per edge whose deadline comes (:class:`FlowingEdges`): the provider checks at the
earliest deadline, and a flowing edge comes due about every two of its intervals, so the
checks grow as the samples do, O(edges x rate) (``python -m bench.flowing_bench``: 3-4 us of
checks a sample from 1 to 1,000 edges).
"""

from __future__ import annotations

import heapq
from collections import deque
from collections.abc import Iterable
from itertools import pairwise

INTERVALS_REMEMBERED = 8
"""Intervals between publications an edge's usual interval is the median of."""
INTERVALS_NEEDED = 3
"""Intervals an edge must have shown before its silence is judged."""
SILENT_INTERVALS = 2.5
"""Usual intervals without a sample after which an edge stopped: one sample missed, and the
next half an interval late."""
MISSED_IN_ROW = 2
"""Whole frames in a row without the edge after which it stopped."""
LATE_MIN_S = 0.004
"""An edge stopped only once a sample is at least this late beyond one usual interval."""


class FlowingEdges:
    """The edges (by name) that deliver now, among those watched (a provider's dynamic push
    edges). :attr:`flowing` changes by :meth:`published` (an edge starts flowing),
    :meth:`missed` and :meth:`silent` (it stops).

    The deadlines wait in a heap, each edge's updated only when it comes due (its samples
    since have moved it on: pushed again), not with every sample, so a check costs O(log
    edges) per edge come due, about every two of its intervals: O(edges x rate log edges) a
    second in all. A check going through every edge each time would cost O(edges^2 x rate),
    the provider waking for each edge's deadline in turn. An edge whose rate rose is checked
    at the deadline of its slower rate, once, a little late: never early."""

    def __init__(self, names: Iterable[str]) -> None:
        self._times: dict[str, deque[float]] = {
            name: deque(maxlen=INTERVALS_REMEMBERED + 1) for name in names
        }
        self._missed = dict.fromkeys(self._times, 0)
        """Whole frames in a row each edge was left out of."""
        self._due: list[tuple[float, str]] = []
        """(deadline, edge) of the flowing edges whose rate is known, a heap; an entry is the
        edge's own while it equals :attr:`_queued`'s, stale otherwise (dropped when it comes
        up)."""
        self._queued: dict[str, float] = {}
        self._usual: dict[str, tuple[float, int]] = {}
        """Each edge's usual interval, and its count of samples when it was worked out: again
        after :data:`INTERVALS_REMEMBERED` more (a sort each time; a check in between is a
        sum)."""
        self._counts = dict.fromkeys(self._times, 0)
        self.flowing: set[str] = set()

    def watches(self, name: str) -> bool:
        return name in self._times

    def published(self, name: str, now: float) -> bool:
        """A sample of ``name`` was published at ``now``; True if the edge starts flowing (its
        token is to be declared) or its rate just became known (its first deadline): the
        checker is to look again."""
        times = self._times.get(name)
        if times is None:
            return False
        times.append(now)
        self._counts[name] += 1
        self._missed[name] = 0
        if name in self.flowing and len(times) != INTERVALS_NEEDED + 1:
            return False
        self.flowing.add(name)
        self._queue(name)
        return True

    def _queue(self, name: str) -> None:
        due = self.deadline(name)
        if due is not None:
            self._queued[name] = due
            heapq.heappush(self._due, (due, name))

    def missed(self, name: str) -> bool:
        """A whole frame came without ``name``; True if that makes :data:`MISSED_IN_ROW` in a
        row and it was flowing (its token is to be withdrawn)."""
        if name not in self._missed:
            return False
        self._missed[name] += 1
        if name in self.flowing and self._missed[name] >= MISSED_IN_ROW:
            self.flowing.discard(name)
            return True
        return False

    def deadline(self, name: str) -> float | None:
        """When ``name``, flowing, stops if nothing more is published; None if its rate is not
        known yet."""
        times = self._times[name]
        if len(times) <= INTERVALS_NEEDED:
            return None
        count = self._counts[name]
        usual, counted = self._usual.get(name, (0.0, -INTERVALS_REMEMBERED))
        if count - counted >= INTERVALS_REMEMBERED or len(times) <= INTERVALS_REMEMBERED:
            intervals = sorted(later - earlier for earlier, later in pairwise(times))
            usual = intervals[len(intervals) // 2]
            self._usual[name] = (usual, count)
        return times[-1] + max(SILENT_INTERVALS * usual, usual + LATE_MIN_S)

    def silent(self, now: float) -> tuple[list[str], float | None]:
        """The flowing edges silent at ``now``, taken out of :attr:`flowing` (their tokens are
        to be withdrawn), and when to check again (None: not before one publishes); no
        flowing edge's deadline is before it."""
        stopped = []
        while self._due and self._due[0][0] <= now:
            due, name = heapq.heappop(self._due)
            if name not in self.flowing or self._queued.get(name) != due:
                continue  # stopped since, or pushed again: a stale entry
            if (self.deadline(name) or due) <= now:
                stopped.append(name)
                self.flowing.discard(name)
                del self._queued[name]
            else:
                self._queue(name)  # its samples since moved it on
        return stopped, self._due[0][0] if self._due else None
