"""The host manager's clock offset (``services/clock_sync.py``) on a stand-in session: an
estimate as soon as an agent answers, kept with its age, and none while none answers."""

from __future__ import annotations

from collections import Counter

from tests.integration.zenoh_helpers import wait_until
from tests.unit.test_clock import LoopbackSession
from ubitrack_agent.net.clock import Clock, parse_clock_status, serve_clock
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.services.clock_sync import ClockSync

KEYS = KeySpace("ubitrack/test")
MS = 10**6


def test_a_host_300_ms_ahead_reports_an_offset_of_minus_300_ms_with_its_age():
    session = LoopbackSession()
    serve_clock(session, KEYS.agent_clock(), Clock())
    counters: Counter[str] = Counter()
    sync = ClockSync(session, KEYS, Clock(300 * MS), counters)
    assert sync.status() is None
    sync.start()
    try:
        status = wait_until(sync.status)
    finally:
        sync.stop()
    assert set(status) == {"offset_ns", "uncertainty_ns", "rtt_ns", "samples", "age_s"}
    assert abs(status["offset_ns"] + 300 * MS) <= status["uncertainty_ns"]
    assert status["samples"] == 8 and counters["clock_estimates"] == 1
    later = sync.status()  # kept, with its age
    assert later["offset_ns"] == status["offset_ns"] and later["age_s"] >= status["age_s"]
    assert parse_clock_status(later).offset_ns == status["offset_ns"]


def test_without_an_agent_it_keeps_asking_and_reports_no_estimate():
    counters: Counter[str] = Counter()
    sync = ClockSync(LoopbackSession(), KEYS, Clock(), counters)
    sync.start()
    try:
        wait_until(lambda: counters["clock_timeouts"] >= 2, timeout=5)
    finally:
        sync.stop()
    assert sync.status() is None and counters["clock_estimates"] == 0
    assert counters["internal_errors"] == 0
