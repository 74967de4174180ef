"""Clocks across hosts: this process's clock, and its offset to the agent's (the reference).

Measurements are stamped in the clock of the host that takes them (``docs/architecture.md``,
"Timestamps"). Each host manager estimates how far its host's clock is from the active agent's
with an NTP-style exchange over a zenoh query (D. L. Mills et al., *Network Time Protocol
Version 4*, RFC 5905, 2010, section 8, "On-Wire Protocol"; F. Cristian, *Probabilistic clock
synchronization*, Distributed Computing 3(3), 1989): the client notes its time ``t1`` when it
asks, the agent answers the reference time ``t2`` at which the query arrived and ``t3`` at which
its reply left, the client notes ``t4`` when the reply is in. Then

* offset ``theta = ((t2 - t1) + (t3 - t4)) / 2``: reference minus local clock, so a local
  time ``t`` is ``t + theta`` on the reference clock;
* round trip ``delta = (t4 - t1) - (t3 - t2)``, the time on the wire both ways.

With one-way delays ``d1`` (there) and ``d2`` (back), ``theta`` is off the true offset by
``(d1 - d2) / 2``, at most ``delta / 2`` in size whatever the asymmetry: the uncertainty of an
exchange is half its round trip. Of several exchanges the one with the smallest round trip is
kept (Cristian's rule; NTP's clock filter, RFC 5905 section 10, picks the lowest delay too),
as queueing only ever adds delay. An estimate's uncertainty grows with its age by the
frequency tolerance ``PHI`` of RFC 5905 (15 ppm), the drift two free-running clocks may have.

The agent's side is :func:`serve_clock` (the queryable ``<root>/agent/clock``, declared while
it is the active agent), the host manager's :func:`measure_offset`
(``ubitrack_agent.services.clock_sync``). A reply that is not a well-formed exchange is a
:class:`ClockRejection`, counted and logged rate-limited by the caller; nothing from the network
raises.

``Settings.clock_offset_ms`` (``--clock-offset-ms``, for tests) makes a process's clock read
that much ahead of the real one: :class:`Clock` applies it, so a host manager, simulator or
adapter started with it behaves as on a host whose clock is off.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from ubitrack_agent.net import logs
from ubitrack_agent.net.config import MAX_CLOCK_OFFSET_NS, Settings
from ubitrack_agent.net.encodings import JSON
from ubitrack_agent.net.json_messages import MessageError, field, load_object

log = logging.getLogger("ubitrack.clock")

PHI = 15e-6
"""Frequency tolerance (s/s) by which an estimate's uncertainty grows with its age (RFC 5905,
section 7.3, ``PHI``)."""
MAX_OFFSET_NS = MAX_CLOCK_OFFSET_NS
"""Largest clock offset the middleware handles (a day): an estimate beyond it is refused."""
MAX_REPLY_BYTES = 1024
"""Largest clock reply read (one takes about 60 bytes)."""
MAX_TIME_NS = 2**63 - 1
DEFAULT_EXCHANGES = 8
"""Exchanges per estimate; the one with the smallest round trip is kept."""
DEFAULT_TIMEOUT_S = 0.5
"""Longest wait for one exchange's reply."""


@dataclass(frozen=True)
class Clock:
    """This process's clock: the real one (``time.time_ns()``) read ``offset_ns`` ahead."""

    offset_ns: int = 0

    @classmethod
    def of(cls, settings: Settings) -> Clock:
        """The clock of a process with ``settings`` (its ``clock_offset_ms``)."""
        return cls(round(settings.clock_offset_ms * 1e6))

    def now_ns(self) -> int:
        """The time now on this clock (Unix nanoseconds)."""
        return time.time_ns() + self.offset_ns

    def reading(self, real_ns: int) -> int:
        """What this clock read at the real time ``real_ns``: a simulator evaluates its world
        at real time and stamps the measurement with this."""
        return real_ns + self.offset_ns


def now_ns(settings: Settings) -> int:
    """The time now on the clock of a process with ``settings`` (:class:`Clock`)."""
    return Clock.of(settings).now_ns()


@dataclass(frozen=True)
class Exchange:
    """One NTP-style exchange (module docstring): ``origin_ns`` (t1) and ``destination_ns``
    (t4) on the local clock, ``receive_ns`` (t2) and ``transmit_ns`` (t3) on the reference."""

    origin_ns: int
    receive_ns: int
    transmit_ns: int
    destination_ns: int

    @property
    def offset_ns(self) -> int:
        """Reference minus local clock, within :attr:`rtt_ns` / 2."""
        return ((self.receive_ns - self.origin_ns) + (self.transmit_ns - self.destination_ns)) // 2

    @property
    def rtt_ns(self) -> int:
        """Time on the wire, both ways (the reference's processing time taken out)."""
        return (self.destination_ns - self.origin_ns) - (self.transmit_ns - self.receive_ns)

    @property
    def valid(self) -> bool:
        """Whether its times are in order on each clock (a clock stepped mid-exchange, or a
        forged reply, breaks that)."""
        return (
            self.destination_ns >= self.origin_ns
            and self.transmit_ns >= self.receive_ns
            and self.rtt_ns >= 0
        )


@dataclass(frozen=True)
class ClockEstimate:
    """A host clock's offset to the reference: ``t_reference ~ t_local + offset_ns``, off by at
    most ``uncertainty_ns`` (half the round trip of the exchange it comes from, grown with age
    by :data:`PHI`); ``rtt_ns`` that round trip; ``samples`` the exchanges it was chosen from."""

    offset_ns: int
    uncertainty_ns: int
    rtt_ns: int
    samples: int

    def aged(self, seconds: float) -> ClockEstimate:
        """The estimate ``seconds`` after it was made: its uncertainty grown by the drift the
        two clocks may have had meanwhile (RFC 5905's dispersion, :data:`PHI`)."""
        growth = math.ceil(PHI * max(seconds, 0.0) * 1e9)
        return ClockEstimate(
            self.offset_ns, self.uncertainty_ns + growth, self.rtt_ns, self.samples
        )

    def as_status(self, age_s: float) -> dict[str, Any]:
        """The host manager's status entry ``clock`` (``docs/protocol.md``, "Clocks")."""
        return {
            "offset_ns": self.offset_ns,
            "uncertainty_ns": self.uncertainty_ns,
            "rtt_ns": self.rtt_ns,
            "samples": self.samples,
            "age_s": round(age_s, 3),
        }


def estimate_offset(exchanges: Iterable[Exchange]) -> ClockEstimate | None:
    """The estimate from the valid exchange with the smallest round trip (module docstring);
    None without a valid exchange."""
    valid = [exchange for exchange in exchanges if exchange.valid]
    if not valid:
        return None
    best = min(valid, key=lambda exchange: exchange.rtt_ns)
    return ClockEstimate(best.offset_ns, (best.rtt_ns + 1) // 2, best.rtt_ns, len(valid))


@dataclass(frozen=True)
class ClockRejection:
    """A clock reply or status entry from the network that is refused, and why (network text:
    log it with ``%r``)."""

    reason: str


def _integer(data: dict[str, Any], name: str, low: int, high: int) -> int:
    value = field(data, name, int)
    if not low <= value <= high:
        raise MessageError("malformed_request", f"{name}: expected an integer in [{low}, {high}]")
    return value


def parse_clock_reply(payload: bytes | None) -> tuple[int, int] | ClockRejection:
    """``(receive_ns, transmit_ns)`` of the agent's reply ``{"receive_ns": t2, "transmit_ns":
    t3}``, or why it is refused; never raises."""
    try:
        data = load_object(payload, MAX_REPLY_BYTES)
        if set(data) != {"receive_ns", "transmit_ns"}:
            raise MessageError("malformed_request", "expected receive_ns and transmit_ns only")
        return (
            _integer(data, "receive_ns", 0, MAX_TIME_NS),
            _integer(data, "transmit_ns", 0, MAX_TIME_NS),
        )
    except MessageError as exc:
        return ClockRejection(exc.reason)


def parse_clock_status(value: Any) -> ClockEstimate | ClockRejection | None:
    """The estimate in a host manager's status entry ``clock`` (:meth:`ClockEstimate.
    as_status`), aged by its ``age_s`` (:meth:`ClockEstimate.aged`); None for ``null`` (no
    estimate yet); a rejection for anything else. Never raises."""
    if value is None:
        return None
    if not isinstance(value, dict):
        return ClockRejection("clock: expected an object or null")
    expected = {"offset_ns", "uncertainty_ns", "rtt_ns", "samples", "age_s"}
    if set(value) != expected:
        return ClockRejection(f"clock: expected the fields {sorted(expected)}")
    try:
        estimate = ClockEstimate(
            _integer(value, "offset_ns", -MAX_OFFSET_NS, MAX_OFFSET_NS),
            _integer(value, "uncertainty_ns", 0, MAX_OFFSET_NS),
            _integer(value, "rtt_ns", 0, MAX_OFFSET_NS),
            _integer(value, "samples", 1, 1_000_000),
        )
        age_s = field(value, "age_s", float)
    except MessageError as exc:
        return ClockRejection(f"clock: {exc.reason}")
    if not 0.0 <= age_s <= 1e9:
        return ClockRejection("clock: age_s: expected seconds in [0, 1e9]")
    return estimate.aged(age_s)


# -- the zenoh side ---------------------------------------------------------------------------


def serve_clock(session: Any, key: str, clock: Clock) -> Any:
    """Declare the queryable ``key`` answering ``clock``'s time to every query (the agent's
    ``<root>/agent/clock``); the caller undeclares it. Replies from zenoh's callback, so no
    queueing adds to the time between ``receive_ns`` and ``transmit_ns``; a query's payload
    and parameters are ignored, so no query can fail it."""

    def reply(query: Any) -> None:
        receive_ns = clock.now_ns()
        answer = {"receive_ns": receive_ns, "transmit_ns": clock.now_ns()}
        query.reply(key, json.dumps(answer), encoding=JSON)

    return session.declare_queryable(key, reply)


def one_exchange(
    session: Any, key: str, clock: Clock, timeout_s: float = DEFAULT_TIMEOUT_S
) -> Exchange | ClockRejection | None:
    """One exchange with the clock queryable ``key`` (the first reply counts); None if nothing
    answered within ``timeout_s``. ``t4 - t1`` is timed on the monotonic clock, so a step of
    the local clock during the exchange does not enter the round trip."""
    origin_ns = clock.now_ns()
    started = time.perf_counter_ns()
    for reply in session.get(key, timeout=timeout_s):
        elapsed = time.perf_counter_ns() - started
        if reply.ok is None:
            return ClockRejection("an error reply")
        times = parse_clock_reply(reply.ok.payload.to_bytes())
        if isinstance(times, ClockRejection):
            return times
        return Exchange(origin_ns, *times, origin_ns + elapsed)
    return None


def measure_offset(
    session: Any,
    key: str,
    clock: Clock,
    counters: Counter[str],
    count: int = DEFAULT_EXCHANGES,
    timeout_s: float = DEFAULT_TIMEOUT_S,
) -> ClockEstimate | None:
    """The estimate from ``count`` exchanges one after the other (:func:`estimate_offset`);
    None if none answered validly. Counts ``clock_exchanges``, ``clock_timeouts`` and
    ``rejected_clock_replies`` (logged rate-limited) in ``counters``. Blocks for up to
    ``count * timeout_s``: run it on a thread of its own, never in a zenoh callback."""
    exchanges = []
    for _ in range(count):
        result = one_exchange(session, key, clock, timeout_s)
        if result is None:
            counters["clock_timeouts"] += 1
            break  # nobody answers: the next estimate tries again
        if isinstance(result, ClockRejection):
            logs.count_problem(
                counters, "rejected_clock_replies", log, "clock reply refused: %r", result.reason
            )
            continue
        counters["clock_exchanges"] += 1
        exchanges.append(result)
    estimate = estimate_offset(exchanges)
    if estimate is not None and abs(estimate.offset_ns) > MAX_OFFSET_NS:
        reason = f"an offset of {estimate.offset_ns} ns, beyond a day"
        logs.count_problem(counters, "rejected_clock_replies", log, "clock refused: %s", reason)
        return None
    return estimate
