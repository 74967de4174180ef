"""Sample buffers that evaluate an edge at any timestamp (DESIGN.md, Synchronisation).

A worker keeps one :class:`SampleBuffer` per input binding; when a trigger sample arrives at
time ``t``, every other input is asked for its value at ``t``. An application's relation keeps
one to answer ``lookup(t)``. The rules:

* a **static** input answers its latest value, whatever its age;
* a **dynamic** input interpolates between the two samples around ``t`` (SLERP and linear for
  poses and rotations, linear for 3D positions, with the covariance rule of
  :func:`ubitrack_agent.core.uncertainty.interpolate_covariance`); other types, or ``t``
  beyond the newest or before the oldest sample, take the nearest sample if it lies within the
  tolerance window, re-stamped to ``t``;
* otherwise the input has no value at ``t`` and the trigger is dropped and counted.

Timestamps are in the sensor host's clock, synchronised with the receiving host's. A sample
stamped more than :data:`MAX_FUTURE_NS` ahead of the receiving host's clock
(:func:`ahead_of_clock`) never enters a buffer: it would stay the newest sample, so the
buffer's latest value, and every trigger instant after it, would wait for the clock to reach
it (one pose stamped a day ahead stopped a relation for a day). Samples from the past are
accepted, so a recording replayed with its original timestamps works, as long as it is never
ahead of the clock: a dynamic buffer keeps the newest ``history`` samples by timestamp, and a
sample older than all of them (beyond the buffer's horizon) is refused by :meth:`SampleBuffer.add`.

This replaces Ubitrack's hand-inserted buffer and interpolation components: the application
never places them. Buffers keep a bounded history, so memory stays bounded.

Applications use the strict form (no value outside the span of the samples, typed errors, in
the manner of tf2's ``lookupTransform``): see :meth:`SampleBuffer.lookup`.
"""

from __future__ import annotations

import bisect
import itertools
from collections import deque

from ubitrack_agent.core import quaternions
from ubitrack_agent.core.errors import ExtrapolationError, MeasurementError, NoDataError
from ubitrack_agent.core.measurements import (
    MAX_FUTURE_NS,
    ErrorPose,
    Measurement,
    Pose,
    Position3D,
    Rotation3D,
)
from ubitrack_agent.core.poses import interpolate_pose
from ubitrack_agent.core.uncertainty import interpolate_covariance

DEFAULT_HISTORY = 64
"""Samples a dynamic input keeps: a second of a 60 Hz tracker."""

MAX_AHEAD_NS = 100 * 10**6
"""How far after its newest measurement a producer predicts a value when asked for one at a
given time (100 ms: a frame or two of display latency with margin; a constant-velocity
prediction of a walking head is off by millimetres at 20 ms, centimetres beyond 100 ms).
``ubitrack_agent.net.time_queries``, ``Relation.predict``."""


def ahead_of_clock(timestamp_ns: int, now_ns: int) -> bool:
    """Whether a sample stamped ``timestamp_ns`` is too far ahead of the clock reading
    ``now_ns`` (``time.time_ns()`` on the receiving host) to be used (:data:`MAX_FUTURE_NS`)."""
    return timestamp_ns - now_ns > MAX_FUTURE_NS


def interpolate(before: Measurement, after: Measurement, timestamp_ns: int) -> Measurement | None:
    """The value at ``timestamp_ns`` between two samples of one edge, or None if the type
    cannot be interpolated."""
    if isinstance(before, Pose | ErrorPose) and isinstance(after, Pose | ErrorPose):
        return interpolate_pose(before, after, timestamp_ns)
    t0, t1 = before.timestamp_ns, after.timestamp_ns
    s = 0.0 if t1 == t0 else (timestamp_ns - t0) / (t1 - t0)
    if isinstance(before, Rotation3D) and isinstance(after, Rotation3D):
        return Rotation3D(timestamp_ns, quaternions.slerp(before.rotation, after.rotation, s))
    if isinstance(before, Position3D) and isinstance(after, Position3D):
        position = (1.0 - s) * before.position + s * after.position
        covariance = None
        if before.covariance is not None and after.covariance is not None:
            covariance = interpolate_covariance(before.covariance, after.covariance, s)
        return Position3D(timestamp_ns, position, covariance)
    return None


def restamp(value: Measurement, timestamp_ns: int) -> Measurement:
    """``value`` carried over to ``timestamp_ns``."""
    return value if value.timestamp_ns == timestamp_ns else value.restamped(timestamp_ns)


class SampleBuffer:
    """Recent samples of one input edge, answering its value at a given time."""

    def __init__(self, static: bool, history: int = DEFAULT_HISTORY) -> None:
        self.static = static
        self._samples: deque[Measurement] = deque(maxlen=1 if static else history)
        self._times: deque[int] = deque(maxlen=self._samples.maxlen)
        self._period: int | None = None

    def __len__(self) -> int:
        return len(self._samples)

    def add(self, sample: Measurement) -> bool:
        """Store a sample; out-of-order samples are inserted in time order. False (nothing
        stored) for a dynamic sample older than every sample of a full buffer: beyond its
        horizon."""
        t = sample.timestamp_ns
        if not self._times or t >= self._times[-1]:
            self._period = None
            self._samples.append(sample)
            self._times.append(t)
            return True
        index = bisect.bisect_right(self._times, t)
        if len(self._samples) == self._samples.maxlen:
            if index == 0:
                return False
            self._samples.popleft()
            self._times.popleft()
            index -= 1
        self._period = None
        self._samples.insert(index, sample)
        self._times.insert(index, t)
        return True

    def shifted(self, delta_ns: int) -> SampleBuffer:
        """A buffer of the same kind holding these samples ``delta_ns`` later (an input whose
        clock offset changed, ``net.spec``); a sample the shift would take out of the
        timestamp range is left out."""
        moved = SampleBuffer(self.static, self._samples.maxlen or DEFAULT_HISTORY)
        for sample in self._samples:
            try:
                moved.add(sample.restamped(sample.timestamp_ns + delta_ns))
            except MeasurementError:
                continue
        return moved

    def latest(self) -> Measurement | None:
        return self._samples[-1] if self._samples else None

    def newest_time(self) -> int | None:
        """Timestamp of the newest sample held, None when empty."""
        return self._times[-1] if self._times else None

    def has_sample_at(self, timestamp_ns: int) -> bool:
        """Whether a sample stamped exactly ``timestamp_ns`` is held."""
        index = bisect.bisect_left(self._times, timestamp_ns)
        return index < len(self._times) and self._times[index] == timestamp_ns

    def typical_period_ns(self) -> int | None:
        """Median gap between the recent samples (None with fewer than three); cached until
        the next sample, as triggers ask for it on every pass."""
        if self._period is None and len(self._times) >= 3:
            recent = list(self._times)[-9:]
            gaps = sorted(b - a for a, b in itertools.pairwise(recent))
            self._period = gaps[len(gaps) // 2]
        return self._period

    def lookup(self, timestamp_ns: int) -> Measurement:
        """The value at ``timestamp_ns``, strictly: a static edge answers its latest value, a
        dynamic one only within the span of its samples (interpolated where the type allows,
        else the nearest sample). Raises :class:`NoDataError` or :class:`ExtrapolationError`."""
        if not self._samples:
            raise NoDataError("no sample received yet")
        oldest, newest = self._times[0], self._times[-1]
        if not self.static and not oldest <= timestamp_ns <= newest:
            raise ExtrapolationError(
                f"timestamp {timestamp_ns} outside the samples held [{oldest}, {newest}]"
            )
        value = self.value_at(timestamp_ns, tolerance_ns=newest - oldest)
        assert value is not None  # inside the span, the nearest sample always qualifies
        return value

    def value_at(self, timestamp_ns: int, tolerance_ns: int) -> Measurement | None:
        """The input's value at ``timestamp_ns`` (see the module docstring), or None."""
        if not self._samples:
            return None
        if self.static:
            return restamp(self._samples[-1], timestamp_ns)
        index = bisect.bisect_left(self._times, timestamp_ns)
        if index < len(self._times) and self._times[index] == timestamp_ns:
            return self._samples[index]
        if 0 < index < len(self._times):
            value = interpolate(self._samples[index - 1], self._samples[index], timestamp_ns)
            if value is not None:
                return value
        candidates = [i for i in (index - 1, index) if 0 <= i < len(self._times)]
        nearest = min(candidates, key=lambda i: abs(self._times[i] - timestamp_ns))
        if abs(self._times[nearest] - timestamp_ns) <= tolerance_ns:
            return restamp(self._samples[nearest], timestamp_ns)
        return None
