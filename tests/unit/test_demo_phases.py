"""The demo's figures per phase (issue 29): its RMS error, its steady state's (the phase after
its first second), its worst second (a 1 s window sliding over the samples), whether within
20 %, and samples handed on to the next phase where it begins."""

from __future__ import annotations

import numpy as np
import pytest

from ubitrack_agent.commands.demo import (
    STEADY_AFTER_S,
    WINDOW_S,
    Phase,
    mean_nees,
    nees,
    rms,
    worst_window_rms,
)
from ubitrack_agent.core import ErrorPose, Pose

START_NS = 1_700_000_000_000_000_000
SECOND_NS = 1_000_000_000


def phase_of(errors_mm: list[float], interval_s: float, name: str = "fused again") -> Phase:
    """A phase begun at START_NS with one sample every ``interval_s`` from then, its rotation
    errors a hundredth of its translation errors, its NEES its translation error."""
    phase = Phase(name, START_NS)
    for index, error in enumerate(errors_mm):
        phase.add(START_NS + int(index * interval_s * 1e9), error, error / 100, 5.0, error)
    phase.ended_ns = START_NS + int(len(errors_mm) * interval_s * 1e9)
    return phase


def brute_worst_window(arrivals_ns: list[int], values: list[float], ended_ns: int) -> float:
    """The definition, quadratic: every window of WINDOW_S from a sample that ends by
    ``ended_ns``."""
    window = int(WINDOW_S * 1e9)
    best = 0.0
    for start in arrivals_ns:
        if start + window > ended_ns:
            continue
        inside = [
            v for t, v in zip(arrivals_ns, values, strict=True) if start <= t < start + window
        ]
        best = max(best, rms(inside))
    return best


def test_worst_window_matches_its_definition_on_irregular_arrivals():
    rng = np.random.default_rng(3)
    arrivals = np.cumsum(rng.uniform(0.001, 0.05, 300) * 1e9).astype(np.int64) + START_NS
    values = list(rng.gamma(2.0, 1.0, 300))
    for ended_ns in (int(arrivals[-1]), int(arrivals[-1]) + SECOND_NS // 3):
        assert worst_window_rms(list(arrivals), values, ended_ns) == pytest.approx(
            brute_worst_window(list(arrivals), values, ended_ns)
        )


def test_worst_window_of_a_span_shorter_than_a_window_is_the_whole_rms():
    arrivals = [START_NS, START_NS + SECOND_NS // 4, START_NS + SECOND_NS // 2]
    ended_ns = START_NS + int(0.9 * SECOND_NS)
    assert worst_window_rms(arrivals, [3.0, 4.0, 0.0], ended_ns) == pytest.approx(
        rms([3.0, 4.0, 0.0])
    )
    assert worst_window_rms([], [], ended_ns) is None


def test_a_transient_in_the_first_second_shows_in_the_worst_second_not_the_steady_state():
    """Five seconds at 80 Hz of 1 mm, the first 0.3 s at 10 mm (a camera-only start)."""
    errors = [10.0 if index < 24 else 1.0 for index in range(400)]
    summary = phase_of(errors, 1 / 80).summary()
    assert summary["steady_error_mm_rms"] == pytest.approx(1.0)
    assert summary["worst_second_mm_rms"] == pytest.approx(np.sqrt((24 * 100 + 56) / 80), abs=1e-3)
    assert summary["error_mm_rms"] == pytest.approx(rms(errors), abs=1e-3)
    assert summary["mm_within_steady"] is False and summary["deg_within_steady"] is False
    assert summary["samples"] == 400 and summary["rate_hz"] == pytest.approx(80.0)


def test_a_steady_phase_is_within_and_its_worst_second_is_no_better_than_its_steady_state():
    rng = np.random.default_rng(5)
    summary = phase_of(list(rng.gamma(4.0, 0.25, 400)), 1 / 80).summary()
    for unit in ("mm", "deg"):
        figures = [summary[f"{k}_{unit}_rms"] for k in ("error", "steady_error", "worst_second")]
        assert all(np.isfinite(figures)), summary
        assert summary[f"worst_second_{unit}_rms"] >= summary[f"steady_error_{unit}_rms"]
        assert summary[f"{unit}_within_steady"] is True


def test_the_steady_state_starts_a_second_after_the_phase():
    """Samples are steady from STEADY_AFTER_S after the phase began, not after its first
    sample: a phase whose samples begin late has a shorter transient part."""
    phase = Phase("camera only", START_NS)
    late = START_NS + int(STEADY_AFTER_S * 1e9) - SECOND_NS // 10
    for index, error in enumerate([9.0, 9.0, 1.0, 1.0, 1.0]):
        phase.add(late + index * SECOND_NS // 20, error, error, 1.0, error)
    phase.ended_ns = late + SECOND_NS
    assert phase.summary()["steady_error_mm_rms"] == pytest.approx(1.0)
    assert phase.summary()["steady_nees_mean"] == pytest.approx(1.0)
    assert phase.summary()["nees_mean"] == pytest.approx(21.0 / 5)


def test_handing_on_moves_the_samples_from_the_next_phase_s_beginning():
    camera = phase_of([5.0] * 10, 0.1, "camera only")
    again = Phase("fused again", START_NS + int(0.75 * SECOND_NS))
    camera.hand_on(again)
    assert camera.ended_ns == again.started_ns
    assert len(camera.errors_mm) == 8 and len(again.errors_mm) == 2
    assert all(t < again.started_ns for t in camera.arrivals_ns)
    assert all(t >= again.started_ns for t in again.arrivals_ns)
    assert len(again.errors_deg) == len(again.latencies_ms) == len(again.nees) == 2


def test_a_sample_s_nees_is_its_left_error_against_its_own_covariance():
    """2 sigma off along x: NEES 4; a rotation of 3 sigma about z at the origin: NEES 9; a pose
    without a covariance is not judged, and the mean skips it."""
    identity, sigma = np.array([0.0, 0.0, 0.0, 1.0]), 1e-3
    covariance = np.eye(6) * sigma**2
    off = ErrorPose(0, identity, np.array([2 * sigma, 0.0, 0.0]), covariance)
    assert nees(off, identity, np.zeros(3)) == pytest.approx(4.0, rel=1e-6)
    turned = np.array([0.0, 0.0, np.sin(1.5 * sigma), np.cos(1.5 * sigma)])
    rotated = ErrorPose(0, turned, np.zeros(3), covariance)
    assert nees(rotated, identity, np.zeros(3)) == pytest.approx(9.0, rel=1e-6)
    plain = nees(Pose(0, identity, np.zeros(3)), identity, np.zeros(3))
    assert np.isnan(plain)
    assert mean_nees([4.0, plain, 8.0]) == pytest.approx(6.0)
    assert mean_nees([plain]) is None
