"""The live view's time series: for each queried relation, one point per polling period (rate,
latency, error against the ground truth), kept over a bounded history for the page's
sparklines. Pure bookkeeping: :mod:`ubitrack_agent.commands.view.watch` feeds it what arrived
on the relation's key."""

from __future__ import annotations

import statistics
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ubitrack_agent.core.measurements import ErrorPose, Measurement, Pose, Position3D


@dataclass
class Period:
    """What arrived on one relation key during one polling period."""

    count: int = 0
    latencies_ms: list[float] = field(default_factory=list)
    latest: Measurement | None = None
    """The sample with the newest timestamp: the one compared with the ground truth."""

    def add(self, arrival_ns: int, sample: Measurement, timed: bool) -> None:
        """Count ``sample``, which arrived at ``arrival_ns`` (wall clock, nanoseconds); with
        ``timed`` (a dynamic relation; a static one is stamped with when it was calibrated),
        also its latency, arrival minus timestamp."""
        self.count += 1
        if timed:
            self.latencies_ms.append((arrival_ns - sample.timestamp_ns) / 1e6)
        if self.latest is None or sample.timestamp_ns >= self.latest.timestamp_ns:
            self.latest = sample

    @property
    def latency_ms(self) -> float | None:
        """The median latency of the period's samples, None without any."""
        return statistics.median(self.latencies_ms) if self.latencies_ms else None


@dataclass(frozen=True)
class Point:
    """One period of one relation: when it ended, and its three values."""

    at_ns: int
    rate_hz: float
    latency_ms: float | None
    error_mm: float | None


class Series:
    """The points of one relation over the last ``length`` periods, oldest first."""

    def __init__(self, length: int) -> None:
        if length < 1:
            raise ValueError(f"a series holds at least one point, not {length}")
        self.points: deque[Point] = deque(maxlen=length)
        self.samples = 0
        """Samples counted since the relation was first watched."""

    def add(self, at_ns: int, period: Period, seconds: float, error_mm: float | None) -> Point:
        """The point of ``period``, which ended at ``at_ns`` and lasted ``seconds``."""
        if seconds <= 0:
            raise ValueError(f"a period lasts a positive time, not {seconds} s")
        point = Point(at_ns, period.count / seconds, period.latency_ms, error_mm)
        self.points.append(point)
        self.samples += period.count
        return point

    def as_json(self, now_ns: int) -> dict[str, Any]:
        """The series as the page draws them: each point's time in seconds relative to
        ``now_ns`` (negative: in the past) and its values, aligned, ``None`` where a period had
        no latency or error; the total sample count."""

        def rounded(value: float | None, digits: int) -> float | None:
            return None if value is None else round(value, digits)

        return {
            "t_s": [round((p.at_ns - now_ns) / 1e9, 3) for p in self.points],
            "rate_hz": [round(p.rate_hz, 2) for p in self.points],
            "latency_ms": [rounded(p.latency_ms, 2) for p in self.points],
            "error_mm": [rounded(p.error_mm, 3) for p in self.points],
            "samples": self.samples,
        }


def position_error_mm(sample: Measurement, truth: Measurement) -> float | None:
    """The distance in millimetres between the positions ``sample`` and ``truth`` give (a
    pose's translation, a 3D position: both in metres), None when either gives none (an image
    position, a projection)."""
    here, there = _position_m(sample), _position_m(truth)
    if here is None or there is None:
        return None
    return float(np.linalg.norm(here - there)) * 1000.0


def _position_m(measurement: Measurement) -> np.ndarray | None:
    if isinstance(measurement, Pose | ErrorPose):
        return measurement.translation
    if isinstance(measurement, Position3D):
        return measurement.position
    return None
