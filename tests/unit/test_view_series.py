"""``ubitrack view``'s series bookkeeping: one point per polling period per relation (rate,
median latency, error against the truth), over a bounded history."""

from __future__ import annotations

import numpy as np
import pytest

from ubitrack_agent.commands.view.series import Period, Series, position_error_mm
from ubitrack_agent.core.measurements import ErrorPose, Pose, Position2D, Position3D

T0 = 1_800_000_000_000_000_000
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def pose(t: int, x: float) -> Pose:
    return Pose(t, IDENTITY, np.array([x, 0.0, 0.0]))


def test_a_period_counts_samples_and_keeps_the_newest_and_the_median_latency():
    period = Period()
    period.add(T0 + 30_000_000, pose(T0 + 20_000_000, 1.0), timed=True)  # 10 ms late
    period.add(T0 + 31_000_000, pose(T0, 2.0), timed=True)  # older sample, 31 ms late
    period.add(T0 + 45_000_000, pose(T0 + 40_000_000, 3.0), timed=True)  # 5 ms late
    assert period.count == 3
    assert period.latency_ms == pytest.approx(10.0)
    assert period.latest is not None and period.latest.translation[0] == 3.0


def test_a_static_relation_has_no_latency_and_an_empty_period_none_at_all():
    period = Period()
    period.add(T0 + 10**12, pose(T0, 1.0), timed=False)  # calibrated long ago
    assert period.count == 1 and period.latency_ms is None
    assert Period().latency_ms is None and Period().latest is None


def test_a_series_keeps_the_last_points_with_times_before_now():
    series = Series(length=3)
    for second in range(5):
        period = Period()
        for k in range(10 * second):
            period.add(T0, pose(T0 - 10**6 * k, 0.0), timed=True)
        series.add(T0 + second * 10**9, period, 2.0, error_mm=None if second == 3 else 1.5)
    shown = series.as_json(now_ns=T0 + 5 * 10**9)
    assert shown["t_s"] == [-3.0, -2.0, -1.0]  # the oldest two dropped
    assert shown["rate_hz"] == [10.0, 15.0, 20.0]  # samples over 2 s periods
    assert shown["error_mm"] == [1.5, None, 1.5]
    assert shown["samples"] == sum(10 * s for s in range(5))  # every sample counted
    assert len(shown["latency_ms"]) == 3 and None not in shown["latency_ms"]


def test_a_series_refuses_nonsense_sizes():
    with pytest.raises(ValueError, match="at least one point"):
        Series(length=0)
    with pytest.raises(ValueError, match="positive time"):
        Series(length=1).add(T0, Period(), 0.0, None)


def test_the_error_is_the_distance_between_positions_in_millimetres():
    truth = pose(T0, 1.0)
    assert position_error_mm(pose(T0, 1.003), truth) == pytest.approx(3.0)
    covariance = np.eye(6) * 1e-6
    measured = ErrorPose(T0, IDENTITY, np.array([1.0, 0.004, 0.0]), covariance)
    assert position_error_mm(measured, truth) == pytest.approx(4.0)
    point = Position3D(T0, np.array([1.0, 0.0, 0.002]))
    assert position_error_mm(point, truth) == pytest.approx(2.0)
    pixel = Position2D(T0, np.array([320.0, 240.0]))  # pixels are no millimetres
    assert position_error_mm(pixel, truth) is None
    assert position_error_mm(truth, pixel) is None
