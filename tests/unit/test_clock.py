"""Clock offsets (``net/clock.py``): the NTP-style estimate is within half the best round trip
of the true offset however asymmetric the delays, the exchange over a stand-in session
measures a clock set off on purpose, and hostile replies and status entries are refused."""

from __future__ import annotations

import json
import time
from collections import Counter
from types import SimpleNamespace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.integration.fuzz_inputs import HOSTILE_NUMBERS, hostile_json, json_values
from ubitrack_agent.net.clock import (
    MAX_OFFSET_NS,
    PHI,
    Clock,
    ClockEstimate,
    ClockRejection,
    Exchange,
    estimate_offset,
    measure_offset,
    parse_clock_reply,
    parse_clock_status,
    serve_clock,
)
from ubitrack_agent.net.config import Settings

DAY_NS = 86_400 * 10**9
MS = 10**6


def exchange_at(real_ns: int, theta_ns: int, out_ns: int, back_ns: int, busy_ns: int) -> Exchange:
    """The exchange a host whose clock reads ``real - theta`` (reference minus local:
    ``theta``) makes with a reference reading real time, starting at ``real_ns``, with one-way
    delays ``out_ns`` and ``back_ns`` and the reference busy ``busy_ns`` in between."""
    arrived = real_ns + out_ns
    left = arrived + busy_ns
    return Exchange(real_ns - theta_ns, arrived, left, left + back_ns - theta_ns)


delays = st.integers(0, 200 * MS)
trips = st.tuples(delays, delays, st.integers(0, MS))


@given(
    theta=st.integers(-DAY_NS, DAY_NS),
    start=st.integers(10**18, 2 * 10**18),
    trips=st.lists(trips, min_size=1, max_size=12),
)
@settings(max_examples=300, deadline=None)
def test_the_error_is_within_half_the_best_round_trip_however_asymmetric(theta, start, trips):
    exchanges = [exchange_at(start + i * 10**9, theta, *trip) for i, trip in enumerate(trips)]
    estimate = estimate_offset(exchanges)
    best = min(out + back for out, back, _ in trips)
    assert estimate.rtt_ns == best  # the reference's busy time is taken out
    assert estimate.samples == len(trips)
    assert abs(estimate.offset_ns - theta) <= estimate.uncertainty_ns
    assert estimate.uncertainty_ns <= best // 2 + 1


def test_the_exchange_with_the_smallest_round_trip_is_chosen():
    theta = -300 * MS
    slow = exchange_at(10**18, theta, 40 * MS, 1 * MS, 0)  # 19.5 ms off
    fast = exchange_at(10**18 + 10**9, theta, 200_000, 100_000, 50_000)
    estimate = estimate_offset([slow, fast, slow])
    assert estimate == ClockEstimate(fast.offset_ns, 150_000, 300_000, 3)
    assert abs(estimate.offset_ns - theta) == 50_000  # half the asymmetry
    assert abs(slow.offset_ns - theta) == 19_500_000


def test_symmetric_delays_give_the_offset_exactly():
    estimate = estimate_offset([exchange_at(10**18, 123_456_789, 5 * MS, 5 * MS, MS)])
    assert estimate.offset_ns == 123_456_789


def test_exchanges_out_of_order_are_ignored_and_none_is_no_estimate():
    backwards = Exchange(100, 50, 40, 200)  # transmitted before it was received
    stepped = Exchange(100, 50, 60, 90)  # the local clock went back mid-exchange
    assert estimate_offset([backwards, stepped]) is None
    assert estimate_offset([]) is None
    good = Exchange(100, 150, 160, 220)
    assert estimate_offset([backwards, good]).samples == 1


def test_an_estimate_grows_uncertain_with_age_by_the_frequency_tolerance():
    estimate = ClockEstimate(-300 * MS, 50_000, 100_000, 8)
    assert estimate.aged(0.0) == estimate
    assert estimate.aged(10.0).uncertainty_ns == 50_000 + round(PHI * 10 * 1e9)
    assert estimate.aged(10.0).offset_ns == estimate.offset_ns


def test_a_clock_reads_its_settings_offset_ahead():
    clock = Clock.of(Settings(clock_offset_ms=300.0))
    assert clock.offset_ns == 300 * MS
    assert clock.reading(10**18) == 10**18 + 300 * MS
    assert Clock.of(Settings(clock_offset_ms=-0.25)).offset_ns == -250_000
    assert Clock().reading(10**18) == 10**18


class LoopbackSession:
    """One queryable; a ``get`` calls it at once and returns its replies (or ``answers``,
    payloads to reply instead)."""

    def __init__(self, answers: list[bytes] | None = None) -> None:
        self.callback = None
        self.answers = answers

    def declare_queryable(self, key, callback):
        self.callback = callback
        return SimpleNamespace(undeclare=lambda: None)

    def get(self, key, timeout=None):
        replies = []
        if self.answers is not None:
            if self.answers:
                replies.append(self._ok(self.answers.pop(0)))
            return replies

        def reply(_key, payload, encoding=None):
            replies.append(self._ok(payload.encode()))

        if self.callback is not None:
            self.callback(SimpleNamespace(reply=reply))
        return replies

    @staticmethod
    def _ok(payload: bytes):
        ok = SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: payload))
        return SimpleNamespace(ok=ok, err=None)


def test_a_host_whose_clock_is_ahead_measures_a_negative_offset():
    session = LoopbackSession()
    serve_clock(session, "ubitrack/test/agent/clock", Clock())
    counters: Counter[str] = Counter()
    local = Clock(300 * MS)
    estimate = measure_offset(session, "ubitrack/test/agent/clock", local, counters)
    assert estimate.samples == 8 == counters["clock_exchanges"]
    assert abs(estimate.offset_ns + 300 * MS) <= estimate.uncertainty_ns
    assert estimate.uncertainty_ns < 50 * MS  # a function call, not a network


def test_without_an_agent_there_is_no_estimate_and_the_timeout_is_counted():
    counters: Counter[str] = Counter()
    assert measure_offset(LoopbackSession(), "k", Clock(), counters) is None
    assert counters["clock_timeouts"] == 1


def test_refused_replies_are_counted_and_the_good_ones_still_count():
    now = time.time_ns()
    good = json.dumps({"receive_ns": now, "transmit_ns": now}).encode()
    answers = [b"nonsense", good, b'{"receive_ns": -1, "transmit_ns": 0}']
    counters: Counter[str] = Counter()
    estimate = measure_offset(LoopbackSession(answers), "k", Clock(), counters, count=3)
    assert counters["rejected_clock_replies"] == 2
    assert estimate is not None and estimate.samples == 1


def test_an_offset_beyond_a_day_is_refused():
    far = json.dumps({"receive_ns": 2 * 10**18, "transmit_ns": 2 * 10**18}).encode()
    counters: Counter[str] = Counter()
    assert measure_offset(LoopbackSession([far]), "k", Clock(), counters, count=1) is None
    assert counters["rejected_clock_replies"] == 1


@given(payload=hostile_json)
@settings(max_examples=200, deadline=None)
def test_any_reply_is_parsed_or_refused(payload):
    result = parse_clock_reply(payload)
    assert isinstance(result, tuple | ClockRejection)


@given(
    name=st.sampled_from(["receive_ns", "transmit_ns"]),
    value=HOSTILE_NUMBERS | st.sampled_from([2**63, -1, True, 1.5, "1"]),
)
def test_replies_with_a_hostile_time_are_refused(name, value):
    reply = {"receive_ns": 10**18, "transmit_ns": 10**18, name: value}
    assert isinstance(parse_clock_reply(json.dumps(reply).encode()), ClockRejection)


STATUS = ClockEstimate(-300 * MS, 40_000, 80_000, 8).as_status(0.0)


def test_a_status_entry_reads_back_as_the_estimate_aged():
    estimate = ClockEstimate(-300 * MS, 40_000, 80_000, 8)
    assert parse_clock_status(estimate.as_status(0.0)) == estimate
    assert parse_clock_status(estimate.as_status(2.0)) == estimate.aged(2.0)
    assert parse_clock_status(None) is None


@given(
    name=st.sampled_from(sorted(STATUS)),
    value=HOSTILE_NUMBERS | st.sampled_from([2**63, MAX_OFFSET_NS + 1, -1, True, "1", 0.5]),
)
def test_status_entries_with_a_hostile_field_are_refused(name, value):
    plausible = (name, value) in (("offset_ns", -1), ("age_s", 0.5), ("age_s", 1e6))
    result = parse_clock_status({**STATUS, name: value})
    assert isinstance(result, ClockEstimate if plausible else ClockRejection)


@given(value=json_values)
def test_any_status_entry_is_parsed_or_refused(value):
    result = parse_clock_status(value)
    assert result is None or isinstance(result, ClockEstimate | ClockRejection)


@pytest.mark.parametrize("entry", [[], "x", 1, {**STATUS, "extra": 1}, {"offset_ns": 0}])
def test_status_entries_of_another_form_are_refused(entry):
    assert isinstance(parse_clock_status(entry), ClockRejection)
