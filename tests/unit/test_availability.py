"""Availability and recovery from sample times (``bench/availability.py``)."""

from __future__ import annotations

import pytest

from bench.availability import (
    availability,
    first_fresh,
    fresh_intervals,
    longest_outage,
    outages,
    recovery,
)


def test_each_sample_covers_until_it_is_older_than_the_window_and_overlaps_merge():
    samples = [(1.0, 1.0), (1.25, 1.125), (3.0, 3.0), (5.0, 4.5)]  # the last arrives stale
    assert fresh_intervals(samples, 0.25) == [(1.0, 1.375), (3.0, 3.25)]


def test_samples_in_any_order_give_the_same_intervals():
    samples = [(2.0, 2.0), (1.0, 1.0), (1.25, 1.25)]
    assert fresh_intervals(samples, 0.5) == [(1.0, 1.75), (2.0, 2.5)]


def test_outages_are_the_uncovered_stretches_clipped_to_the_span():
    intervals = [(0.0, 1.0), (2.0, 3.0), (5.0, 9.0)]
    assert outages(intervals, 0.5, 6.0) == [(1.0, 2.0), (3.0, 5.0)]
    assert outages(intervals, -1.0, 10.0) == [(-1.0, 0.0), (1.0, 2.0), (3.0, 5.0), (9.0, 10.0)]
    assert outages([], 0.0, 1.0) == [(0.0, 1.0)]


def test_availability_is_the_covered_fraction():
    intervals = [(0.0, 1.0), (2.0, 3.0), (5.0, 9.0)]
    assert availability(intervals, 0.0, 10.0) == pytest.approx(0.6)
    assert availability(intervals, 5.0, 9.0) == 1.0
    assert availability([], 0.0, 4.0) == 0.0
    assert longest_outage(intervals, 0.0, 10.0) == 2.0
    assert longest_outage(intervals, 5.0, 9.0) == 0.0


def test_recovery_ends_with_the_last_outage_after_the_event():
    intervals = [(0.0, 10.3), (10.8, 11.0), (11.5, 20.0)]  # two lapses after an event at 10
    assert recovery(intervals, 10.0, 20.0) == pytest.approx(1.5)
    assert recovery(intervals, 12.0, 20.0) == 0.0  # fresh throughout
    assert recovery(intervals, 10.0, 25.0) is None  # still down at the end


def test_first_fresh_is_the_first_covered_moment_after_the_event():
    intervals = [(0.0, 1.0), (2.5, 3.0)]
    assert first_fresh(intervals, 1.5) == 1.0
    assert first_fresh(intervals, 0.5) == 0.0
    assert first_fresh(intervals, 3.0) is None
