"""Trigger timestamps that wait briefly for the other inputs to catch up.

Interpolating an input at a trigger's time ``t`` needs a sample of that input at or after
``t``. Samples of one instant travel separately (a camera publishes each feature's 2D edge on
its own key, and unsynchronised trackers sample at different instants), so a trigger is held
until every live dynamic input has a sample at or after ``t``, or until its wait is over
(one and a half periods of the slowest live input, capped); then it is evaluated (nearest
sample within the tolerance window where there is nothing to interpolate). An input sampled at
the same instants as the trigger's own (the other features of one camera frame, the other
bodies of one tracker frame: its newest sample's time is one the trigger's input also has)
travels with it, so it is waited for only :data:`SAME_INSTANT_WAIT_NS` after the latest sample
of that instant arrived: a feature hidden in this frame does not hold the frame's pose back by
a period, and a frame published slowly (a loaded machine) is still waited for while its
samples keep coming. Every dynamic binding may
trigger: an instant is computed once, and a trigger older than the last instant computed is
stale.

An input that is *new* (fewer samples than it takes to know its period: none, or one or two)
is waited for up to the cap when every input is needed to compute (``needed``: no space
expansion, where a hidden feature may never come): without its next sample there is nothing to
interpolate at the trigger's time, so not waiting would only drop the instant. Before, such an
input counted as not live until its third sample, so the first instants of a flow whose inputs
arrive at the same instants but one after the other (a component reading a tracker and another
component's output derived from the same tracker frame) were dropped, three periods in all
(300 ms at 10 Hz, issue 28's time to a first sample).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

from ubitrack_agent.core.timeline import SampleBuffer

LIVE_PERIODS = 2.0
"""An input whose newest sample is older than this many of its periods before a trigger is
not waited for (an occluded feature, a tracker that lost its target)."""
WAIT_PERIODS = 1.5
"""A trigger waits up to this many periods of the slowest live input for its next sample."""
SAME_INSTANT_WAIT_NS = 5_000_000
"""How long a trigger waits for an input sampled at the same instants as its own after the
latest sample of that instant (5 ms: the samples of one frame are published back to back,
within a fraction of a millisecond on an idle machine; the margin is for a loaded one)."""


def _live(
    buffer: SampleBuffer, timestamp_ns: int, default_period_ns: int, needed: bool = False
) -> bool:
    """Whether a trigger at ``timestamp_ns`` waits for ``buffer``'s input (module docstring)."""
    newest = buffer.newest_time()
    known = buffer.typical_period_ns()
    if known is None and needed:
        return True  # new: nothing can be computed without its next sample
    period = known or default_period_ns
    return newest is not None and newest >= timestamp_ns - LIVE_PERIODS * period


def lagging(
    buffers: Iterable[SampleBuffer],
    timestamp_ns: int,
    default_period_ns: int,
    needed: bool = False,
) -> bool:
    """Whether some live input has no sample at or after ``timestamp_ns`` yet (``needed``:
    every input is needed to compute, module docstring)."""
    for b in buffers:
        if _live(b, timestamp_ns, default_period_ns, needed):
            newest = b.newest_time()
            if newest is None or newest < timestamp_ns:
                return True
    return False


def _same_instants(buffer: SampleBuffer, trigger: SampleBuffer) -> bool:
    newest = buffer.newest_time()
    return newest is not None and trigger.has_sample_at(newest)


def wait_for(
    buffers: Iterable[SampleBuffer],
    timestamp_ns: int,
    default_period_ns: int,
    cap_ns: int,
    trigger: SampleBuffer | None = None,
    needed: bool = False,
) -> float:
    """Seconds a trigger at ``timestamp_ns`` (on the input holding ``trigger``) may wait for
    the live inputs' next samples (``needed``: every input is needed to compute, so a new one
    is waited for up to ``cap_ns``: module docstring)."""
    waits = []
    for b in buffers:
        if not _live(b, timestamp_ns, default_period_ns, needed):
            continue
        period = b.typical_period_ns()
        if trigger is not None and _same_instants(b, trigger):
            waits.append(SAME_INSTANT_WAIT_NS)
        elif period is None and needed:
            waits.append(cap_ns)
        else:
            waits.append(WAIT_PERIODS * (period or default_period_ns))
    return min(max(waits, default=0), cap_ns) * 1e-9


class PendingTriggers:
    """Trigger timestamps (ns) with their deadlines (monotonic seconds), oldest first."""

    def __init__(self) -> None:
        self.last_done: int | None = None
        self.deadlines: dict[int, float] = {}
        """The deadline of each trigger held, by timestamp (read it to know whether any is
        held: a worker asks before every sample, and a method call would cost a hop more)."""

    def add(self, timestamp_ns: int, now: float, wait_s: float, extend: bool = False) -> bool:
        """Hold a trigger for at most ``wait_s``; False if that instant is pending, done, or
        older than the last done. With ``extend``, another sample of a pending instant holds
        it until ``now + wait_s`` instead: while the samples of one frame keep arriving, the
        wait for the frame's missing ones runs from the latest (and is the short one once
        enough of them are in)."""
        if not self._after_last_done(timestamp_ns):
            return False
        if timestamp_ns in self.deadlines:
            if extend:
                self.deadlines[timestamp_ns] = now + wait_s
            return False
        self.deadlines[timestamp_ns] = now + wait_s
        return True

    def finish(self, timestamp_ns: int) -> bool:
        """Take a trigger that needs no wait as done at once (nothing is pending); False if
        it is not newer than the last done."""
        last = self.last_done
        if last is not None and timestamp_ns <= last:  # _after_last_done, one call fewer a hop
            return False
        self.last_done = timestamp_ns
        return True

    def _after_last_done(self, timestamp_ns: int) -> bool:
        return self.last_done is None or timestamp_ns > self.last_done

    def due(self, now: float, caught_up: Callable[[int], bool]) -> list[int]:
        """Remove and return, oldest first, the triggers whose inputs caught up or whose wait
        is over; stops at the first that must still wait, so instants stay in order."""
        ready = []
        for timestamp_ns in sorted(self.deadlines):
            if not (caught_up(timestamp_ns) or now >= self.deadlines[timestamp_ns]):
                break
            del self.deadlines[timestamp_ns]
            ready.append(timestamp_ns)
            self.last_done = timestamp_ns
        return ready

    def next_deadline(self) -> float | None:
        return min(self.deadlines.values()) if self.deadlines else None

    def clear(self) -> None:
        self.deadlines.clear()
