"""Availability and recovery of an application's data, from the times of its samples (pure).

An application holds fresh data at time ``t`` when it has received, by ``t``, a correct sample
stamped no earlier than ``t - window``: a sample stamped ``stamp`` that arrived at ``arrival``
(both in seconds on one clock) covers ``[arrival, stamp + window)``, and nothing if it arrived
older than ``window``. Which samples are correct is the caller's choice (against truth).
"""

from __future__ import annotations

from collections.abc import Iterable

Interval = tuple[float, float]


def fresh_intervals(samples: Iterable[tuple[float, float]], window: float) -> list[Interval]:
    """The sorted, disjoint intervals covered by ``(arrival, stamp)`` samples."""
    spans = sorted((arrival, stamp + window) for arrival, stamp in samples)
    merged: list[Interval] = []
    for begin, end in spans:
        if end <= begin:
            continue
        if merged and begin <= merged[-1][1]:
            merged[-1] = (merged[-1][0], max(merged[-1][1], end))
        else:
            merged.append((begin, end))
    return merged


def outages(intervals: list[Interval], start: float, end: float) -> list[Interval]:
    """The stretches of ``[start, end)`` that ``intervals`` (sorted, disjoint) leave uncovered."""
    gaps: list[Interval] = []
    cursor = start
    for begin, finish in intervals:
        if finish <= cursor:
            continue
        if begin >= end:
            break
        if begin > cursor:
            gaps.append((cursor, begin))
        cursor = max(cursor, finish)
    if cursor < end:
        gaps.append((cursor, end))
    return gaps


def availability(intervals: list[Interval], start: float, end: float) -> float:
    """The fraction of ``[start, end)`` covered by ``intervals``."""
    down = sum(finish - begin for begin, finish in outages(intervals, start, end))
    return 1.0 - down / (end - start)


def recovery(intervals: list[Interval], event: float, end: float) -> float | None:
    """Seconds from ``event`` until the data is fresh again for good within ``[event, end)``:
    the end of the last outage after ``event``, 0 if there is none, None if it lasts to
    ``end`` (not recovered)."""
    gaps = outages(intervals, event, end)
    if not gaps:
        return 0.0
    if gaps[-1][1] >= end:
        return None
    return gaps[-1][1] - event


def first_fresh(intervals: list[Interval], event: float) -> float | None:
    """Seconds from ``event`` to the first moment covered at or after it (0 if it is covered),
    None if there is none."""
    for begin, end in intervals:
        if end > event:
            return max(begin, event) - event
    return None


def longest_outage(intervals: list[Interval], start: float, end: float) -> float:
    """The longest uncovered stretch of ``[start, end)``, in seconds (0 if none)."""
    return max((finish - begin for begin, finish in outages(intervals, start, end)), default=0.0)
