"""One display time for the 3D view: every live relation's value at the same instant.

The relations that place the frames arrive at their own rates and latencies (a camera's pose at
30 Hz, a tracker's at 60 Hz, a fusion's output after both), so their latest samples are from
different instants, and composing them (:func:`~.frames.place`) would join poses taken up to a
frame apart while things move. Instead each relation keeps its recent samples (:class:`Recent`)
and is evaluated at one **display time**: the newest instant every current relation has
reached, the oldest of their newest samples. A dynamic relation is interpolated there (SLERP
and linear, with the covariance rule of
:func:`~ubitrack_agent.core.uncertainty.interpolate_covariance`; the synchronisation of Pustka
et al. 2006, section 3, and of Ubitrack's buffers); a static relation is held at its latest
value. A dynamic relation with no sample within :data:`CURRENT_S` of the newest (a tracker that
stopped, a component's output that no longer changes) does not hold the display time back: it
is held at its latest value, and its **skew**, how far its value is from the display time, is
reported, as is that of a relation whose samples do not reach back to the display time. The
display then lags the freshest sample by about the slowest current relation's period and
latency (``behind_ms``).

O(relations log history) per alignment; O(history) memory per relation, and per sample
added in time order O(1).
"""

from __future__ import annotations

import bisect
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass

from ubitrack_agent.core.measurements import Measurement
from ubitrack_agent.core.timeline import interpolate

CURRENT_S = 0.25
"""A dynamic relation whose newest sample is older than this, against the newest sample of
any relation, is held rather than holding the display time back."""

HISTORY = 128
"""Samples a dynamic relation keeps: 2 s at 60 Hz, :data:`CURRENT_S` at 500 Hz."""


class Recent:
    """The recent samples of one relation in time order (the latest only, if ``static``)."""

    def __init__(self, static: bool, history: int = HISTORY) -> None:
        self.static = static
        self._times: deque[int] = deque(maxlen=1 if static else history)
        self._samples: deque[Measurement] = deque(maxlen=self._times.maxlen)

    def __len__(self) -> int:
        return len(self._times)

    def add(self, sample: Measurement) -> None:
        """Keep ``sample``; one older than all of a full history is dropped."""
        t = sample.timestamp_ns
        if not self._times or t >= self._times[-1]:
            self._times.append(t)
            self._samples.append(sample)
            return
        index = bisect.bisect_right(self._times, t)
        if len(self._times) == self._times.maxlen:
            if index == 0:
                return
            self._times.popleft()
            self._samples.popleft()
            index -= 1
        self._times.insert(index, t)
        self._samples.insert(index, sample)

    def latest(self) -> Measurement:
        return self._samples[-1]

    def at(self, t: int) -> tuple[Measurement, int]:
        """The value at ``t`` and its skew (ns): interpolated between the samples around
        ``t`` (skew 0), else the nearest sample and how far it is from ``t``."""
        index = bisect.bisect_left(self._times, t)
        if index < len(self._times) and self._times[index] == t:
            return self._samples[index], 0
        if 0 < index < len(self._times):
            value = interpolate(self._samples[index - 1], self._samples[index], t)
            if value is not None:
                return value, 0
        nearest = min(
            (i for i in (index - 1, index) if 0 <= i < len(self._times)),
            key=lambda i: abs(self._times[i] - t),
        )
        return self._samples[nearest], abs(self._times[nearest] - t)

    def newest_time(self) -> int:
        return self._times[-1]


@dataclass(frozen=True)
class Aligned:
    """A relation's value at the display time: ``mode`` is ``interpolated`` (at the display
    time, or its nearest sample when its samples do not reach it), ``held`` (a dynamic
    relation no longer current: its latest value) or ``static`` (its latest value);
    ``skew_ns`` how far from the display time the value was measured (0 when interpolated
    within its samples or static)."""

    value: Measurement
    mode: str
    skew_ns: int


@dataclass(frozen=True)
class Alignment:
    """The display time (None without a dynamic relation), the newest sample's time, and
    each relation's :class:`Aligned` value."""

    display_ns: int | None
    newest_ns: int | None
    relations: dict[str, Aligned]


def align(recent: Mapping[str, Recent]) -> Alignment:
    """Every relation of ``recent`` with a sample, evaluated at the display time (the module
    docstring)."""
    filled = {name: samples for name, samples in recent.items() if len(samples)}
    newest_of = {n: s.newest_time() for n, s in filled.items() if not s.static}
    if not newest_of:
        return Alignment(
            None, None, {n: Aligned(s.latest(), "static", 0) for n, s in filled.items()}
        )
    newest = max(newest_of.values())
    current = {n: t for n, t in newest_of.items() if newest - t <= CURRENT_S * 1e9}
    display = min(current.values())
    relations = {}
    for name, samples in filled.items():
        if samples.static:
            relations[name] = Aligned(samples.latest(), "static", 0)
        elif name not in current:
            relations[name] = Aligned(samples.latest(), "held", display - newest_of[name])
        else:
            value, skew = samples.at(display)
            relations[name] = Aligned(value, "interpolated", skew)
    return Alignment(display, newest, relations)
