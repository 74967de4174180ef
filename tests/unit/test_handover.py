"""The hand-over rules of a relation key (``ubitrack_agent.services.handover``): one stream on
the key while a new producer takes it over from an old one, or the old one dies."""

from __future__ import annotations

import json
from collections import Counter

import numpy as np
from hypothesis import example, given
from hypothesis import strategies as st

from ubitrack_agent.core import MeasurementError, decode, encode
from ubitrack_agent.core.measurements import WORKER, ErrorPose, Pose
from ubitrack_agent.services.handover import (
    CLAIM_TIMEOUT_S,
    DEFAULT_QUIET_S,
    HOLDER_LOST_IN_ROW,
    INTERVALS_REMEMBERED,
    TAKE_BACK_RATIO,
    WARM_S,
    KeyHandOver,
)

MS = 1_000_000


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def pose(t_ms: int, variance: float = 1e-6) -> ErrorPose:
    return ErrorPose(t_ms * MS, [0, 0, 0, 1], [1, 2, 3], variance * np.eye(6))


class Bus:
    """The relation key and its hand-over key, delivered at once to every producer (the
    putting one too: its rules ignore their own samples, which a ``Watch`` no longer gets
    from zenoh, and must stay right if they get one), or, with ``held``, the
    hand-over's messages kept until :meth:`deliver` (a message in flight); the producers'
    tokens, which :meth:`die` takes away."""

    def __init__(self, warm_s: float = 0.0) -> None:
        self.warm_s = warm_s
        """How long a producer computes before it may claim (``WARM_S``; none by default)."""
        self.clock = Clock()
        self.producers: list[KeyHandOver] = []
        self.counters: list[Counter[str]] = []
        self.wire: list[tuple[int, str, bytes]] = []
        self.messages: list[dict] = []
        self.held: list[bytes] | None = None

    def producer(self, name: str | None = None) -> KeyHandOver:
        """A producer starting (its id ``name``, if given): it sees the others' tokens, asks who
        holds the key and the key's latest sample first (``Watch``)."""
        counters: Counter[str] = Counter()
        hand_over = KeyHandOver(
            "ubitrack/d/relation/C/A", counters, self._send, self.clock, self.warm_s
        )
        hand_over.producer = name or hand_over.producer
        for other in self.producers:
            other.joined(hand_over.producer)
            hand_over.joined(other.producer)
            if (reply := other.holding()) is not None:
                hand_over.receive(reply)
        if self.wire:
            hand_over.observe(self.wire[-1][2], latest=True)
        self.producers.append(hand_over)
        self.counters.append(counters)
        return hand_over

    def die(self, producer: KeyHandOver) -> None:
        """Its process ends: its token leaves."""
        self.producers.remove(producer)
        for other in self.producers:
            other.left(producer.producer)

    def _send(self, data: bytes) -> None:
        self.messages.append(json.loads(data))
        if self.held is not None:
            self.held.append(data)
            return
        for producer in self.producers:
            producer.receive(data)

    def deliver(self) -> None:
        """The messages in flight arrive, and from now on at once."""
        held, self.held = self.held or [], None
        for data in held:
            for producer in self.producers:
                producer.receive(data)

    def offer(self, hand_over: KeyHandOver, value: ErrorPose) -> bool:
        """Whether ``value`` was put at once (one held back may be put later, when the key
        becomes free)."""
        payload = encode(value)

        def put() -> None:
            self.wire.append((value.timestamp_ns, hand_over.producer, payload))
            for producer in self.producers:
                producer.observe(payload)

        if not hand_over.admit(value, put):
            return False
        put()
        return True

    def stamps(self) -> list[int]:
        return [t // MS for t, _, _ in self.wire]


def test_a_lone_producer_puts_every_sample_in_order_and_never_one_twice():
    bus = Bus()
    alone = bus.producer()
    assert [bus.offer(alone, pose(t)) for t in (10, 20, 20, 15, 30)] == [1, 1, 0, 0, 1]
    assert bus.counters[0]["relation_not_after"] == 2
    assert bus.messages == [{"claim": alone.producer, "after": 10 * MS}]  # nobody to answer


def test_a_new_producer_holds_back_until_ready_then_claims_and_takes_over_after_the_answer():
    bus = Bus()
    old = bus.producer()
    assert bus.offer(old, pose(0))
    new = bus.producer()
    for t in range(10, 100, 10):  # both compute every instant; the new one is converging
        bus.clock.now += 0.01
        assert bus.offer(old, pose(t))
        assert not bus.offer(new, pose(t, variance=4e-6))
    assert bus.counters[1]["relation_held"] == 9 and len(bus.messages) == 1  # the old one's
    bus.clock.now += 0.01
    assert not bus.offer(new, pose(100, variance=0.9e-6))  # ready: claims, not put at once
    claim, answer = bus.messages[1:]
    assert claim["claim"] == new.producer
    assert answer == {"yield": old.producer, "last": 90 * MS, "to": new.producer}
    assert bus.stamps()[-1] == 100  # put when the answer came: after the holder's last
    assert not bus.offer(old, pose(100))  # the old one stopped before it answered
    assert bus.offer(new, pose(110, variance=2e-6))  # taken: no longer compared
    assert [who for _, who, _ in bus.wire] == [old.producer] * 10 + [new.producer] * 2
    assert bus.stamps() == list(range(0, 120, 10))
    assert bus.counters[0]["relation_yielded"] == 1 and bus.counters[1]["relation_taken"] == 1


def test_a_producer_as_certain_claims_only_once_it_has_computed_for_the_warm_up_time():
    """A fusion restored after a crash is as certain as its warm replica holding the key from
    its first estimates on, which claim a certainty its state has not earned: it claims only
    after ``WARM_S``."""
    bus = Bus(warm_s=WARM_S)
    old = bus.producer()
    assert bus.offer(old, pose(0))
    new = bus.producer()
    steps = round(WARM_S / 0.01)
    for t in range(1, steps + 1):  # as certain as the holder from the first estimate on
        bus.clock.now += 0.01
        assert bus.offer(old, pose(10 * t))
        assert not bus.offer(new, pose(10 * t))
    assert bus.counters[1]["relation_held"] == steps and len(bus.messages) == 1  # no claim
    bus.clock.now += 0.01
    assert not bus.offer(new, pose(10 * steps + 10))  # warm now: claims
    assert bus.messages[-2]["claim"] == new.producer and bus.counters[1]["relation_taken"] == 1
    better = bus.producer()  # clearly more certain: claims with its first estimate
    bus.clock.now += 0.01
    assert not bus.offer(better, pose(10 * steps + 20, variance=0.4e-6))
    assert bus.messages[-2]["claim"] == better.producer


def test_a_less_certain_producer_holds_back_for_as_long_as_the_holder_puts():
    """Rule 2 has no time limit: a flow less certain than the one putting (a spare, or a
    camera alone beside a fusion on standby) waits until the agent stops the holder."""
    bus = Bus()
    old, new = bus.producer(), bus.producer()
    for t in range(10, 15_000, 10):  # 15 s at 100 Hz, longer than any standby
        bus.clock.now += 0.01
        assert bus.offer(old, pose(t))
        assert not bus.offer(new, pose(t, variance=2e-6))
    assert not any(m.get("claim") == new.producer for m in bus.messages)
    bus.die(old)  # stopped by the agent: the key is free (rule 5)
    bus.clock.now += 0.01
    assert bus.offer(new, pose(15_000, variance=2e-6))


def test_a_producer_starting_before_the_holders_next_sample_does_not_claim_the_key():
    """A flow started beside a holder putting at 30 Hz computes its first estimate before the
    holder's next sample (the key's latest not seen either): the key is not quiet yet, so the
    less certain newcomer holds back, and once it sees the holder's sample, rule 2 keeps it
    held; after a quiet time of watching with nothing seen, it claims (rule 4)."""
    bus = Bus()
    old = holding(bus)
    wire, bus.wire = bus.wire, []  # the key's latest sample not seen by the newcomer
    new = bus.producer()
    bus.wire = wire
    bus.clock.now += 0.005
    assert not bus.offer(new, pose(15, variance=4e-6))
    assert not any(m.get("claim") == new.producer for m in bus.messages)
    assert bus.counters[1]["relation_held"] == 1
    bus.clock.now += 0.028
    assert bus.offer(old, pose(43))  # the holder's next sample
    bus.clock.now += 0.005
    assert not bus.offer(new, pose(48, variance=4e-6))
    assert not any(m.get("claim") == new.producer for m in bus.messages)
    # a holder alive but silent from the start: the newcomer claims a quiet time after it began
    # to watch, not before
    quiet = Bus()
    holding(quiet)
    wire, quiet.wire = quiet.wire, []
    late = quiet.producer()
    quiet.wire = wire
    quiet.clock.now += 0.05
    assert not quiet.offer(late, pose(60, variance=4e-6))
    assert not any(m.get("claim") == late.producer for m in quiet.messages)
    quiet.clock.now += 0.06
    assert not quiet.offer(late, pose(110, variance=4e-6))  # claims; put on the answer
    assert {"claim": late.producer, "after": None} in quiet.messages  # nothing seen on the key
    assert quiet.wire[-1][:2] == (110 * MS, late.producer)


def test_the_time_from_the_keys_latest_sample_answered_to_the_next_is_no_interval():
    """A newcomer is answered the key's latest sample as it starts, and the 30 Hz holder's
    next sample comes 12 ms later: that is no interval of the holder's, so one slow frame of
    the holder (60 ms) does not make the key quiet for the less certain newcomer."""
    bus = Bus()
    old = bus.producer()
    for t in (0, 33, 66):
        bus.clock.now += 0.033
        assert bus.offer(old, pose(t))
    bus.clock.now += 0.021
    new = bus.producer()  # answered the sample of 66 ms, 21 ms after it was put
    bus.clock.now += 0.012
    assert bus.offer(old, pose(99))
    for t in (119, 144):  # the holder's next frame is 60 ms late: the newcomer computes twice
        bus.clock.now += 0.020 if t == 119 else 0.025
        assert not bus.offer(new, pose(t, variance=4e-6))
    bus.clock.now += 0.015
    assert bus.offer(old, pose(159))
    assert not any(m.get("claim") == new.producer for m in bus.messages)
    assert bus.counters[1]["relation_held"] == 2


def test_the_keys_latest_answered_after_the_holders_samples_changes_nothing():
    """The answer to a starting producer's question may come after the holder's next sample:
    it is no put of the holder's then (its arrival 5 ms later made a 5 ms interval, a quiet
    time of 20 ms, and the key quiet for the less certain newcomer 25 ms on)."""
    bus = Bus()
    old = holding(bus)
    wire, bus.wire = bus.wire, []
    new = bus.producer()
    bus.wire = wire
    bus.clock.now += 0.033
    assert bus.offer(old, pose(43))
    bus.clock.now += 0.005
    new.observe(bus.wire[-2][2], latest=True)  # the answer: the holder's sample of 10 ms
    assert new.quiet_s() == DEFAULT_QUIET_S  # one sample of the holder seen, no interval
    bus.clock.now += 0.020
    assert not bus.offer(new, pose(68, variance=4e-6))
    assert not any(m.get("claim") == new.producer for m in bus.messages)


def test_a_spare_takes_the_key_within_a_sample_when_the_holder_loses_a_sensor():
    """A spare (``agent.spares``: the fusion of the two sensors left, started beside the
    fusion of the best two) waits while the holder is the more certain; the holder's better
    tracker stops, its estimate degrades to the camera's, and the spare claims at its next
    sample: one degraded sample reaches the key at most."""
    bus = Bus()
    fused, spare = bus.producer(), bus.producer()
    for t in range(10, 1000, 10):
        bus.clock.now += 0.01
        assert bus.offer(fused, pose(t, variance=1e-6))
        assert not bus.offer(spare, pose(t, variance=2e-6))
    degraded = [1000, 1010, 1020]  # the better tracker gone: the camera alone in the fusion
    for t in degraded:
        bus.clock.now += 0.01
        bus.offer(fused, pose(t, variance=40e-6))
        bus.offer(spare, pose(t, variance=2e-6))
    assert bus.messages[-2:] == [
        {"claim": spare.producer, "after": 1000 * MS},
        {"yield": fused.producer, "last": 1000 * MS, "to": spare.producer},
    ]
    by = {t // MS: who for t, who, _ in bus.wire}
    assert [by[t] for t in degraded] == [fused.producer, spare.producer, spare.producer]
    assert bus.stamps() == list(range(10, 1030, 10))  # one stream
    assert bus.counters[1]["relation_taken"] == 1


def test_a_producer_that_gave_the_key_away_does_not_take_it_back_for_a_holder_less_certain():
    """A fusion on standby running on the camera alone gave the key to the camera-only flow;
    the raw estimate's covariance jumps (a feature hidden) where the filter's does not: the
    fusion does not take the key back for that, or the two would take it from each other in
    turn (the demo's camera-only phase)."""
    bus = Bus()
    fused, camera = bus.producer(), bus.producer()
    bus.clock.now += 0.01
    bus.offer(fused, pose(10, variance=1.0e-6))
    bus.offer(camera, pose(10, variance=0.9e-6))  # as certain for once: claims, taken
    for t in range(20, 100, 10):
        bus.clock.now += 0.01
        assert bus.offer(camera, pose(t, variance=40e-6 if t == 50 else 2e-6))
        assert not bus.offer(fused, pose(t, variance=1.0e-6))
    assert bus.counters[0]["relation_taken_back"] == 0


def putting_to_40(bus: Bus) -> KeyHandOver:
    """A producer that put every 10 ms from 10 to 40 ms, the key's holder."""
    first = bus.producer()
    for t in range(10, 50, 10):
        bus.clock.now += 0.01
        assert bus.offer(first, pose(t, variance=1e-6))
    return first


def given_away_at_50(bus: Bus) -> tuple[KeyHandOver, KeyHandOver]:
    """:func:`putting_to_40`, and a clearly more certain producer starting at 50 ms, which
    claims the key: the first yields it."""
    first = putting_to_40(bus)
    second = bus.producer()
    bus.clock.now += 0.01
    bus.offer(first, pose(50, variance=1e-6))
    bus.offer(second, pose(50, variance=0.2e-6))  # clearly better: claims, the first yields
    return first, second


def test_a_producer_that_gave_the_key_away_takes_it_back_when_the_holder_lost_an_input():
    """Rule 6: the fusion of the A.R.T. tracker and the camera gave the key to the fusion of
    the better tracker and the camera; the better tracker gone, that one runs on the camera
    alone (on standby, for seconds): after HOLDER_LOST_IN_ROW of its samples in a row at least
    ten times as uncertain as its least of the last LOST_WINDOW_S, the first fusion takes the
    key back; one stream."""
    bus = Bus()
    art, better = given_away_at_50(bus)
    for t in range(60, 100, 10):
        bus.clock.now += 0.01
        assert bus.offer(better, pose(t, variance=0.2e-6))
        assert not bus.offer(art, pose(t, variance=1e-6))
    # The better tracker gone: the filter grows uncertain over a few samples, to the camera's.
    t, variance, over = 100, 0.2e-6, 0
    while not bus.counters[0]["relation_taken_back"]:
        bus.clock.now += 0.01
        variance = min(40e-6, 2 * variance)
        over = over + 1 if variance >= 0.2e-6 / TAKE_BACK_RATIO else 0
        assert bus.offer(better, pose(t, variance=variance))
        assert not bus.offer(art, pose(t, variance=1e-6))  # the claim, at the last of these
        t += 10
        assert t < 1000, "never taken back"
    assert over == HOLDER_LOST_IN_ROW  # ten times its least of the window, three in a row
    assert bus.messages[-2:] == [
        {"claim": art.producer, "after": (t - 10) * MS},
        {"yield": better.producer, "last": (t - 10) * MS, "to": art.producer},
    ]
    bus.clock.now += 0.01
    assert not bus.offer(better, pose(t, variance=40e-6))
    assert bus.offer(art, pose(t, variance=1e-6))
    assert bus.counters[0]["relation_taken_back"] == 1
    stamps = bus.stamps()
    assert stamps == sorted(set(stamps))  # every instant once, in order


def test_a_holder_less_certain_all_along_keeps_the_key_from_the_one_that_gave_it_away():
    """Rule 6 reads a lost input from the holder's own covariance, not from the comparison:
    the A.R.T. tracker gone, the fusion (on standby, on the camera alone) gave the key to the
    camera-only flow; the filter's estimate is far more certain than the raw one all along,
    and it does not take the key back for that (the agent chose the camera-only flow)."""
    bus = Bus()
    fused = putting_to_40(bus)
    camera = bus.producer()
    bus.clock.now += 0.01
    bus.offer(camera, pose(50, variance=40e-6))
    bus.offer(fused, pose(50, variance=40e-6))  # the tracker gone: as uncertain as the camera
    bus.clock.now += 0.01
    bus.offer(camera, pose(60, variance=40e-6))  # ready (warm-up none here): claims, taken
    variance = 40e-6
    for t in range(70, 400, 10):
        bus.clock.now += 0.01
        variance = max(2e-6, 0.7 * variance)  # the filter settles on the camera alone
        assert bus.offer(camera, pose(t, variance=40e-6))
        assert not bus.offer(fused, pose(t, variance=variance))  # kept away
    assert bus.counters[0]["relation_taken_back"] == 0


def holding(bus: Bus) -> KeyHandOver:
    """A producer that has put two samples, 10 ms apart."""
    old = bus.producer()
    for t in (0, 10):
        bus.clock.now += 0.01
        bus.offer(old, pose(t))
    return old


def test_with_the_old_producer_gone_the_new_one_puts_at_once():
    bus = Bus()
    old = holding(bus)
    bus.producers.remove(old)  # its sensor died, then the agent stopped it
    new = bus.producer()
    bus.clock.now += 1.0
    assert bus.offer(new, pose(1010, variance=1e-2))
    assert bus.messages[-1] == {"claim": new.producer, "after": 1010 * MS}
    assert bus.counters[1]["relation_held"] == 0


def test_a_holder_only_late_yields_to_the_producer_that_found_the_key_quiet():
    """A fusion waiting for an input that stopped is quiet for a while, then puts again."""
    bus = Bus()
    old = holding(bus)
    new = bus.producer()
    bus.clock.now += 0.2  # the old one waits for its camera
    assert not bus.offer(new, pose(210, variance=4e-6))  # quiet, its holder alive: claims
    assert bus.wire[-1][:2] == (210 * MS, new.producer)  # put on the answer (after 10)
    bus.clock.now += 0.01
    assert not bus.offer(old, pose(200))  # it yielded to the claim
    assert not bus.offer(old, pose(220))
    assert bus.offer(new, pose(220, variance=4e-6))
    assert [who for _, who, _ in bus.wire][2:] == [new.producer] * 2


def test_a_holder_only_late_and_one_finding_the_key_quiet_never_put_one_instant_each():
    """The claim and its answer in flight while the late holder puts the instants it held:
    the repeated instants of the switch bench (a fusion, its camera gone, quiet, then putting
    the instant the A.R.T.-only flow had put at once)."""
    bus = Bus()
    old = holding(bus)
    new = bus.producer()
    bus.clock.now += 0.2
    bus.held = []
    assert not bus.offer(new, pose(210, variance=4e-6))  # claims; nothing put before the answer
    for t in range(20, 220, 10):  # the old one's held triggers, computed late
        assert bus.offer(old, pose(t))
    bus.deliver()  # it yields after 210: what the new one held back is not after that
    bus.clock.now += 0.01
    assert not bus.offer(old, pose(220))
    assert bus.offer(new, pose(220, variance=4e-6))
    assert bus.stamps() == list(range(0, 230, 10))  # each instant once, in order
    assert bus.wire[-1][1] == new.producer and bus.counters[1]["relation_put_when_free"] == 0


def test_a_producer_held_back_puts_its_newest_sample_as_soon_as_the_holders_token_leaves():
    """Rule 5: the holder killed (or stopped by the agent) frees the key at once, not after
    the quiet time; the sample held back goes out then, if it is after the newest."""
    bus = Bus()
    old = holding(bus)
    standby = bus.producer()
    bus.clock.now += 0.01
    assert bus.offer(old, pose(20))
    assert not bus.offer(standby, pose(20, variance=4e-6))  # not after the newest
    bus.clock.now += 0.01
    assert not bus.offer(standby, pose(30, variance=4e-6))  # less certain: held back
    bus.die(old)  # before it put 30
    assert bus.stamps() == [0, 10, 20, 30] and bus.wire[-1][1] == standby.producer
    assert bus.messages[-1] == {"claim": standby.producer, "after": 30 * MS}
    assert bus.counters[1]["relation_holder_left"] == 1
    assert bus.counters[1]["relation_put_when_free"] == 1
    bus.clock.now += 0.001  # well within the quiet time of the old one's intervals
    assert bus.offer(standby, pose(40, variance=4e-6))


def test_a_holder_that_lost_a_provider_gives_the_key_up_and_the_one_beside_it_puts_at_once():
    """Rule 7: the chain on a tracker that left (kept by the agent on standby, its process and
    token alive) gives the key up when the tracker's token leaves, not a quiet time later; the
    fusion waiting beside it puts its sample held back at once, and what the chain still
    computes (a sample on its way) is not put."""
    bus = Bus()
    chain = holding(bus)
    fusion = bus.producer()
    bus.clock.now += 0.01
    assert bus.offer(chain, pose(20))
    assert not bus.offer(fusion, pose(30, variance=4e-6))  # less certain: held back
    chain.input_stopped()
    assert bus.messages[-2] == {"free": chain.producer, "last": 20 * MS}
    assert bus.messages[-1] == {"claim": fusion.producer, "after": 30 * MS}
    assert bus.stamps() == [0, 10, 20, 30] and bus.wire[-1][1] == fusion.producer
    assert bus.counters[0]["relation_given_up"] == 1
    assert bus.counters[1]["relation_holder_gave_up"] == 1
    assert bus.counters[1]["relation_put_when_free"] == 1
    assert not chain.holds and fusion.holds
    assert not bus.offer(chain, pose(40))  # on its way when the tracker left
    bus.clock.now += 0.001  # at once, not after a quiet time
    assert bus.offer(fusion, pose(40, variance=4e-6))
    assert bus.stamps() == [0, 10, 20, 30, 40]


def given_up_to_a_fusion(until_ms: int) -> tuple[Bus, KeyHandOver, KeyHandOver]:
    """The chain held the key and lost its input (rule 7); the fusion beside it, less certain,
    put every 20 ms from 30 ms until before ``until_ms``."""
    bus = Bus()
    chain = holding(bus)
    fusion = bus.producer()
    bus.clock.now += 0.01
    assert not bus.offer(fusion, pose(20, variance=4e-6))
    chain.input_stopped()
    for t in range(30, until_ms, 20):
        bus.clock.now += 0.02
        assert bus.offer(fusion, pose(t, variance=4e-6))
    return bus, chain, fusion


def test_a_holder_that_lost_a_provider_takes_the_key_back_when_it_computes_again():
    """Rule 7 then rule 6: the tracker back, the chain computes again after a quiet spell, no
    less certain than the holder, and claims the key back."""
    bus, chain, fusion = given_up_to_a_fusion(700)
    assert not bus.offer(chain, pose(700))  # back after 0.67 s: claims
    assert bus.messages[-1] == {"yield": fusion.producer, "last": 690 * MS, "to": chain.producer}
    assert chain.holds and bus.stamps()[-1] == 700


def test_a_holder_whose_edge_stopped_for_a_moment_takes_the_key_back_when_its_token_returns():
    """Rule 7 then rule 6 after a short silence (a body hidden for 0.1 s): the chain's edge
    token is back, and its next estimate, no less certain than the holder's, claims the key
    back at once; without the token back, the same estimate after so short a silence does not
    (it yields to whoever holds the key, as before)."""
    for token_back in (True, False):
        bus, chain, fusion = given_up_to_a_fusion(130)
        if token_back:
            chain.input_back()
        bus.clock.now += 0.005
        assert not bus.offer(chain, pose(125))
        assert chain.holds is token_back
        if token_back:
            assert bus.messages[-1] == {
                "yield": fusion.producer,
                "last": 110 * MS,
                "to": chain.producer,
            }
        assert bus.counters[0]["relation_taken_back"] == int(token_back)


def test_a_provider_leaving_frees_nothing_unless_its_producer_holds_the_key_beside_another():
    """Rule 7 hands the key on only to a producer alive beside the holder: a holder alone
    keeps it (nobody could do better, and a provider it did not really need costs nothing),
    and a producer not holding it has nothing to give."""
    bus = Bus()
    alone = holding(bus)
    said = len(bus.messages)  # its claim when it began
    alone.input_stopped()
    bus.clock.now += 0.01
    assert bus.offer(alone, pose(20)) and len(bus.messages) == said
    assert not bus.counters[0]["relation_given_up"]
    beside = bus.producer()
    bus.clock.now += 0.01
    assert not bus.offer(beside, pose(30, variance=4e-6))
    beside.input_stopped()
    assert len(bus.messages) == said and not bus.counters[1]["relation_given_up"]
    assert bus.offer(alone, pose(30))


def test_of_several_producers_beside_a_holder_that_leaves_one_takes_the_key():
    """Rule 5 with three producers (a flow on standby, a new one, the holder): when the holder
    leaves, only the first by id takes the key at once; the other takes it for the holder, so
    no instant is put twice (both compute the same instants)."""
    bus = Bus()
    old = holding(bus)
    waiting = [bus.producer(), bus.producer()]
    bus.clock.now += 0.01
    assert bus.offer(old, pose(20))
    for producer in waiting:
        assert not bus.offer(producer, pose(30, variance=4e-6))  # less certain: held back
    bus.die(old)
    first, other = sorted(waiting, key=lambda p: p.producer)
    assert bus.stamps() == [0, 10, 20, 30] and bus.wire[-1][1] == first.producer
    for t in (40, 50):
        bus.clock.now += 0.01
        assert bus.offer(first, pose(t, variance=4e-6))
        assert not bus.offer(other, pose(t, variance=5e-6))  # less certain: held back
    assert bus.stamps() == [0, 10, 20, 30, 40, 50]  # each instant once


def test_a_producer_that_is_not_the_holder_leaving_frees_nothing():
    bus = Bus()
    old = holding(bus)
    first, second = bus.producer(), bus.producer()
    bus.clock.now += 0.01
    assert bus.offer(old, pose(20))
    assert not bus.offer(second, pose(30, variance=4e-6))
    bus.die(first)
    assert bus.stamps()[-1] == 20 and not bus.counters[2]["relation_holder_left"]
    assert not bus.offer(second, pose(30, variance=4e-6))  # still held back beside the holder


def test_a_sample_held_back_is_not_put_when_the_holder_put_a_newer_one_before_it_left():
    bus = Bus()
    old = holding(bus)
    standby = bus.producer()
    bus.clock.now += 0.01
    assert not bus.offer(standby, pose(15, variance=4e-6))
    assert bus.offer(old, pose(20))
    bus.die(old)
    assert bus.stamps() == [0, 10, 20]  # rule 1 first
    assert bus.offer(standby, pose(30, variance=4e-6))


def test_an_unanswered_claim_is_said_again_while_the_holder_puts_and_taken_once_it_is_quiet():
    """A holder that puts on but does not answer (its answer late on a loaded machine, or a
    message lost): the claimer puts nothing while the holder puts, so no instant goes out
    twice, and says its claim again every CLAIM_TIMEOUT_S; once the key is quiet (the holder
    stopped or hung), it puts."""
    bus = Bus()
    old, new = bus.producer(), bus.producer()
    old.receive = lambda data: None
    bus.offer(old, pose(0))
    bus.clock.now += 0.01
    assert not bus.offer(new, pose(10, variance=0.5e-6))  # claims: nobody answers
    t = 10
    while bus.clock.now - 100.01 < 3 * CLAIM_TIMEOUT_S:
        assert bus.offer(old, pose(t))
        bus.clock.now += 0.01
        assert not bus.offer(new, pose(t + 5, variance=0.5e-6))
        t += 10
    claims = [m for m in bus.messages if m.get("claim") == new.producer]
    assert len(claims) == 1 + bus.counters[1]["relation_claims_repeated"] >= 3
    assert bus.counters[1]["relation_claims_unanswered"] == 0
    assert {who for _, who, _ in bus.wire} == {old.producer}
    bus.clock.now += 0.2  # the holder stops putting
    t += 200
    while not bus.offer(new, pose(t, variance=0.5e-6)):
        bus.clock.now += 0.05
        t += 50
    assert bus.counters[1]["relation_claims_unanswered"] == 1
    assert bus.wire[-1][1] == new.producer
    stamps = bus.stamps()
    assert stamps == sorted(set(stamps))  # every instant once, in order


def test_the_old_producer_puts_again_when_the_new_one_dies():
    bus = Bus()
    old = bus.producer()
    bus.offer(old, pose(0))
    new = bus.producer()
    bus.clock.now += 0.01
    bus.offer(old, pose(10))
    bus.offer(new, pose(10, variance=0.5e-6))  # claims; old yields
    bus.clock.now += 0.01
    assert bus.offer(new, pose(20))
    assert not bus.offer(old, pose(20)) and not bus.offer(old, pose(30))
    bus.die(new)
    bus.clock.now += 0.001  # its token gone: at once, not after the quiet time
    assert bus.offer(old, pose(40))


def test_a_producer_that_gave_the_key_away_takes_it_back_when_a_lost_input_is_back():
    """Rule 6: a fusion that lost its tracker gave the key to the camera-only flow; when the
    tracker's data is back in it (its estimate far more certain at once), it claims the key
    back; merely more certain than the holder (a better filter), it does not, so two flows of
    similar quality never take the key from each other in turn."""
    bus = Bus()
    fused = bus.producer()
    bus.offer(fused, pose(0, variance=40e-6))  # its tracker lost: the camera's uncertainty
    camera = bus.producer()
    bus.clock.now += 0.01
    bus.offer(fused, pose(10, variance=40e-6))
    bus.offer(camera, pose(10, variance=30e-6))  # ready: claims, the fusion yields
    for t in range(20, 60, 10):
        bus.clock.now += 0.01
        assert bus.offer(camera, pose(t, variance=30e-6))
        assert not bus.offer(fused, pose(t, variance=15e-6))  # better than the holder: kept away
    assert bus.counters[0]["relation_taken_back"] == 0
    bus.clock.now += 0.01
    assert bus.offer(camera, pose(60, variance=30e-6))
    assert not bus.offer(fused, pose(70, variance=0.2e-6))  # the tracker is back: claims
    assert bus.messages[-2:] == [
        {"claim": fused.producer, "after": 60 * MS},
        {"yield": camera.producer, "last": 60 * MS, "to": fused.producer},
    ]
    assert bus.stamps()[-1] == 70  # held back, put when the answer came
    bus.clock.now += 0.01
    assert not bus.offer(camera, pose(80, variance=30e-6))
    assert bus.offer(fused, pose(80, variance=0.2e-6))
    assert bus.counters[0]["relation_taken_back"] == 1
    assert bus.counters[1]["relation_taken_back"] == 0
    assert bus.stamps() == list(range(0, 90, 10))  # one stream: every instant once, in order


def test_a_producer_that_gave_the_key_away_takes_it_back_when_it_puts_again_after_quiet():
    """Rule 6, the other way to lose an input: a chain on one tracker goes quiet when the
    tracker stops and resumes when it returns, then at least as certain as the holder."""
    bus = Bus()
    chain = bus.producer()
    bus.offer(chain, pose(0, variance=2e-6))
    camera = bus.producer()
    bus.clock.now += 0.01
    bus.offer(chain, pose(10, variance=2e-6))
    bus.offer(camera, pose(10, variance=1e-6))  # claims, the chain yields
    for t in range(20, 1000, 20):  # the tracker stopped: the chain is quiet
        bus.clock.now += 0.02
        assert bus.offer(camera, pose(t, variance=100e-6))
    assert not bus.offer(chain, pose(1000, variance=200e-6))  # back, but less certain
    bus.clock.now += 0.6
    assert bus.offer(camera, pose(1010, variance=100e-6))
    bus.clock.now += 0.01
    assert not bus.offer(chain, pose(1020, variance=2e-6))  # quiet 0.6 s, back: claims
    assert bus.messages[-1] == {"yield": camera.producer, "last": 1010 * MS, "to": chain.producer}
    assert bus.counters[0]["relation_taken_back"] == 1 and bus.stamps()[-1] == 1020


def test_a_producer_that_gave_the_key_away_claims_it_when_the_holder_goes_quiet():
    """The fusion of the A.R.T. tracker and the camera gave the key to a chain on the better
    tracker (clearly more certain). Right after, it waits the longest quiet time (a 100 ms
    hiccup of the new flow's first samples takes nothing); once it knows INTERVALS_REMEMBERED
    of the chain's intervals, the chain quiet for three of them (the better tracker left; its
    process, and token, alive) makes it claim the key, which the chain answers: about 30 ms of
    silence, not QUIET_BOUNDS_S's 0.5 s (the switch bench, session 23). One stream."""
    bus = Bus()
    fused, chain = given_away_at_50(bus)
    bus.clock.now += 0.1  # the new flow's first interval, uneven
    for t in range(60, 60 + 10 * (INTERVALS_REMEMBERED + 1), 10):
        assert bus.offer(chain, pose(t, variance=0.2e-6))
        assert not bus.offer(fused, pose(t, variance=1e-6))
        bus.clock.now += 0.01
    assert bus.counters[0]["relation_taken"] == 0  # the hiccup took nothing
    last = t
    for t in range(last + 10, last + 100, 10):  # the chain quiet from here: its tracker left
        if bus.offer(fused, pose(t, variance=1e-6)) or bus.counters[0]["relation_taken"]:
            break
        bus.clock.now += 0.01
    assert t - last <= 40  # three intervals of 10 ms, and the one that finds it quiet
    assert bus.messages[-2:] == [
        {"claim": fused.producer, "after": last * MS},
        {"yield": chain.producer, "last": last * MS, "to": fused.producer},
    ]
    bus.clock.now += 0.01
    assert bus.offer(fused, pose(t + 10, variance=1e-6))
    stamps = bus.stamps()
    assert stamps == sorted(set(stamps)) and stamps[-1] == t + 10


def test_one_dropped_frame_of_the_holder_does_not_triple_the_wait_for_it():
    """A chain on a 60 Hz tracker that drops a frame now and then (2 % of a simulated A.R.T.
    tracker's) holds the key; the fusion it took the key from waits beside it. After one 33 ms
    interval among 17 ms ones the chain counts as gone after three usual intervals (51 ms) and
    at least one usual interval longer than that 33 ms, not after three of its longest (99 ms):
    the switch bench's "better tracker leaves" waited 144 ms after a 42 ms interval. A silence
    as long as the longest recent one plus a usual interval takes nothing."""
    bus = Bus()
    fused, chain = given_away_at_50(bus)
    t = 50
    for interval in [17] * INTERVALS_REMEMBERED + [33] + [17] * 3:  # one frame dropped
        t += interval
        bus.clock.now += interval / 1000
        assert bus.offer(chain, pose(t, variance=0.2e-6))
    assert abs(fused.quiet_s() - 3 * 0.017) < 1e-9  # three usual intervals: 51 > 33 + 17 ms
    last = t
    bus.clock.now += 0.049  # a silence of 49 ms, longer than any recent one: not yet quiet
    assert not bus.offer(fused, pose(last + 49, variance=1e-6))
    assert bus.counters[0]["relation_taken"] == 0
    bus.clock.now += 0.004  # 53 ms: the chain's tracker left, the chain is quiet
    assert not bus.offer(fused, pose(last + 53, variance=1e-6))  # claims; put on the answer
    assert bus.messages[-2:] == [
        {"claim": fused.producer, "after": last * MS},
        {"yield": chain.producer, "last": last * MS, "to": fused.producer},
    ]
    assert bus.stamps()[-1] == last + 53


def test_a_stall_of_the_producer_waiting_does_not_make_it_wait_the_longest():
    """The fusion that gave the key to the chain on the better tracker stalls for 70 ms (a
    loaded machine), then gets the chain's samples of that time at once: a silence longer than
    the quiet time, but a hiccup, not a new stream, so the chain's intervals are kept (the
    quiet time grows by it) and, when the chain's tracker then leaves, the fusion claims the key
    after that quiet time, not after the longest (0.5 s: one gap of 502 ms in the switch bench,
    session 30)."""
    bus = Bus()
    fused, chain = given_away_at_50(bus)
    t = 50
    for _ in range(INTERVALS_REMEMBERED + 2):
        t += 17
        bus.clock.now += 0.017
        assert bus.offer(chain, pose(t, variance=0.2e-6))
    bus.clock.now += 0.07  # the fusion's process stalled: the chain's next samples, at once
    for _ in range(4):
        t += 17
        assert bus.offer(chain, pose(t, variance=0.2e-6))
        bus.clock.now += 0.0001
    assert abs(fused.quiet_s() - (0.07 + 0.017)) < 1e-6  # the stall's silence, and one more
    last = t
    for silence in range(10, 200, 10):  # the chain's tracker left: the chain is quiet
        bus.clock.now += 0.01
        put = bus.offer(fused, pose(last + silence, variance=1e-6))
        if not put and bus.counters[0]["relation_taken"]:
            break
    assert silence <= 100  # about 87 ms, not 500
    assert bus.messages[-2:] == [
        {"claim": fused.producer, "after": last * MS},
        {"yield": chain.producer, "last": last * MS, "to": fused.producer},
    ]


def test_the_quiet_time_is_three_usual_intervals_and_longer_than_the_longest():
    """:meth:`KeyHandOver.quiet_s` from the other producer's intervals: the usual one is the
    upper quartile of its timestamps' intervals (a fusion of 60 Hz and 30 Hz sensors puts
    samples 1 and 16 ms apart: 16 ms; a backlog delivered at once does not shorten it), a
    silence at least one usual interval longer than the longest between arrivals is needed, and
    the bounds hold."""
    bus = Bus()
    watcher = bus.producer()
    stall = [0.1] + [0.0001] * 5 + [0.0167] * 2  # six samples of a 60 Hz chain put together
    for arrivals, stamps, expected in [
        ([0.016, 0.001] * 4, [0.016, 0.001] * 4, 3 * 0.016),  # the usual one is the long one
        ([0.017] * 7 + [0.1], [0.017] * 8, 0.1 + 0.017),  # a hiccup: longer than it
        (stall, [0.0167] * 8, 0.1 + 0.0167),  # the backlog's bunching changes nothing
        (stall[1:], [0.0167] * 7, 3 * 0.0167),  # nor when the stall itself is forgotten
        ([0.005], [0.005], 0.02),  # the lower bound
        ([0.3] * 8, [0.3] * 8, 0.5),  # the upper bound
    ]:
        intervals = watcher._other_intervals
        intervals.clear()
        stamp_ns = 10**12
        intervals.add(None, stamp_ns)
        for arrival, between in zip(arrivals, stamps, strict=True):
            stamp_ns += round(between * 1e9)
            intervals.add(arrival, stamp_ns)
        assert abs(watcher.quiet_s() - expected) < 1e-6, arrivals


def test_a_producer_starting_waits_for_its_question_who_holds_a_quiet_key():
    """Its question still open (the reply in flight), a quiet key may have a holder only late:
    claimed and held back; the question closed with no holder alive, the key is taken with the
    sample held back."""
    bus = Bus()
    old = holding(bus)
    bus.die(old)
    new = bus.producer()
    new.asking = True
    bus.clock.now += 0.2
    assert not bus.offer(new, pose(210)) and bus.stamps() == [0, 10]
    new.asked()
    assert bus.stamps() == [0, 10, 210] and bus.wire[-1][1] == new.producer
    assert bus.offer(new, pose(220))


def test_a_quiet_holder_alive_that_does_not_answer_loses_the_key_after_the_claim_timeout():
    """Its token up, its messages lost (or its process hung)."""
    bus = Bus()
    old = holding(bus)
    new = bus.producer()
    old.receive = lambda data: None
    bus.clock.now += 0.2
    assert not bus.offer(new, pose(210))  # claims
    bus.clock.now += CLAIM_TIMEOUT_S / 2
    assert not bus.offer(new, pose(220))
    bus.clock.now += CLAIM_TIMEOUT_S / 2
    assert bus.offer(new, pose(230)) and bus.counters[1]["relation_claims_unanswered"] == 1


def two_producers(instants, new_from: int) -> tuple[Bus, KeyHandOver, KeyHandOver | None]:
    """The old producer alone for ``new_from`` instants (at 60 Hz), then with a new one; at
    each instant, in the order drawn, the old one offers it, and the new one if drawn too,
    with a covariance drawn relative to the old one's."""
    bus = Bus()
    old = bus.producer()
    new = None
    for i, (old_first, both, ratio) in enumerate(instants):
        bus.clock.now += 1 / 60
        if i == new_from:
            new = bus.producer()
        offers = [(old, pose(i * 16))]
        if new is not None and both:
            offers.append((new, pose(i * 16, variance=ratio * 1e-6)))
        for producer, value in offers if old_first else offers[::-1]:
            bus.offer(producer, value)
    return bus, old, new


INSTANTS = st.lists(st.tuples(st.booleans(), st.booleans(), st.floats(0.1, 4.0)), max_size=80)


@given(INSTANTS, st.integers(1, 60))
def test_two_producers_of_the_same_instants_put_every_instant_at_most_once_in_order(
    instants, new_from
):
    bus, _, _ = two_producers(instants, new_from)
    stamps = [t for t, _, _ in bus.wire]
    assert stamps == sorted(set(stamps))


@given(
    st.lists(st.tuples(st.booleans(), st.just(True), st.floats(0.5, 4.0)), max_size=80),
    st.integers(1, 60),
)
def test_once_the_new_producer_puts_the_old_one_puts_no_more(instants, new_from):
    """While the new one offers every instant (it does not die) and loses no input: its
    covariance stays within a factor of ten of its earlier ones (rule 6 gives the key back
    from a holder ten times as uncertain as before, three samples in a row)."""
    bus, old, new = two_producers(instants, new_from)
    who = [producer for _, producer, _ in bus.wire]
    if new is not None and new.producer in who:
        assert old.producer not in who[who.index(new.producer) :]


STEPS = st.lists(
    st.tuples(
        st.lists(st.sampled_from((0, 1, 2)), max_size=3, unique=True),  # who offers, in order
        st.lists(st.sampled_from((0.1, 0.5, 1.0, 2.0, 40.0)), min_size=3, max_size=3),
        st.sampled_from(
            (None, None, None, None, "start", "die", "quiet", "hold", "deliver", "lost", "back")
        ),
        st.integers(0, 2),
    ),
    max_size=120,
)


@given(STEPS, st.permutations("abcdef"))
@example([([0], [1.0] * 3, None, 0), ([1, 0], [0.5, 40.0, 1.0], "start", 1)] * 3, "abcdef")
def test_any_producers_coming_going_and_changing_certainty_never_put_an_instant_twice(steps, names):
    """Up to three producers of one relation (a flow, its spare, a flow on standby, a new
    one), each at any moment as certain as any other or ten times less (a sensor lost or
    back), starting, dying, falling quiet and losing a provider they need in any order, the
    hand-over's messages delayed: every instant on the key is put once at most, in order
    (rules 1 to 7 together), and
    while the messages flow, one producer at most holds the key. The producers' ids are drawn
    too (rule 5 and the claims' tie-break order by them)."""
    names = list(names)
    bus = Bus()
    slots: list[KeyHandOver | None] = [bus.producer(names.pop()), None, None]
    for i, (offering, variances, event, who) in enumerate(steps):
        if event == "start" and slots[who] is None and names:
            slots[who] = bus.producer(names.pop())
        elif event == "die" and slots[who] is not None:
            bus.die(slots[who])
            slots[who] = None
        elif event == "quiet":
            bus.clock.now += 0.6
        elif event == "hold" and bus.held is None:
            bus.held = []  # the hand-over's messages in flight from now
        elif event == "deliver":
            bus.deliver()
        elif event == "lost" and slots[who] is not None:
            slots[who].input_stopped()  # rule 7
        elif event == "back" and slots[who] is not None:
            slots[who].input_back()  # rule 6
        bus.clock.now += 1 / 60
        for k in offering:
            if slots[k] is not None:
                bus.offer(slots[k], pose(16 * (i + 1), variance=variances[k] * 1e-6))
        if bus.held is None:
            assert sum(1 for p in slots if p is not None and p.holds) <= 1
    stamps = bus.stamps()
    assert stamps == sorted(set(stamps))


def test_a_relay_payload_is_judged_by_its_decoded_value_and_garbage_is_let_through():
    bus = Bus()
    relay = bus.producer()
    assert relay.admit(encode(Pose(10 * MS, [0, 0, 0, 1], [0, 0, 0])))
    assert not relay.admit(encode(Pose(10 * MS, [0, 0, 0, 1], [0, 0, 0])))
    assert relay.admit(b"\xc1 not a measurement")  # refused where it came in, not here


@given(st.binary(max_size=200))
def test_what_does_not_decode_on_the_key_is_ignored(payload):
    bus = Bus()
    producer = bus.producer()
    try:
        decode(payload, level=WORKER)
    except MeasurementError:
        producer.observe(payload)  # never raises, and changes nothing
        assert producer.admit(pose(1)) and not bus.counters[0]


@given(
    st.one_of(
        st.binary(max_size=300),
        st.dictionaries(
            st.sampled_from(["claim", "yield", "last", "after", "holds", "to", "free", "x"]),
            st.one_of(st.none(), st.integers(), st.text(max_size=5), st.booleans()),
            max_size=3,
        ).map(lambda d: json.dumps(d).encode()),
    )
)
@example(b'{"yield": "", "last": null}')  # an answer to nobody's claim: ignored, not counted
@example(b'{"yield": "", "last": null, "to": 3}')  # refused and counted
def test_hand_over_messages_of_any_form_are_answered_or_refused_and_counted(payload):
    bus = Bus()
    holder = bus.producer()
    bus.offer(holder, pose(0))
    before = sum(bus.counters[0].values())
    sent = len(bus.messages)
    holder.receive(payload)
    counted = bus.counters[0]["rejected_hand_over_messages"]
    replies = bus.messages[sent:]
    # Either refused and counted, or a well-formed claim answered, or ignored as harmless.
    claimer = json.loads(payload).get("claim") if replies else None
    answer = {"yield": holder.producer, "last": 0, "to": claimer}
    assert counted or not replies or replies == [answer]
    assert sum(bus.counters[0].values()) in (before, before + 1)
