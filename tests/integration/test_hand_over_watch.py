"""The hand-over watch of a relation key (``ubitrack_agent.services.handover.Watch``) on real
zenoh sessions: its subscriber takes only other processes' samples (``Locality.REMOTE``), so a
producer's own puts do not come back to it, and the other producers of the key in the same
process are shown its samples by ``Watch.put``. Real sessions on loopback: a hub (another
process's session, as far as zenoh is concerned) and a container's session with two
producers of one key."""

from __future__ import annotations

import contextlib
import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest

from tests.integration.zenoh_helpers import Collector, free_port, hub_session, wait_until
from ubitrack_agent.core import ErrorPose, decode, encode
from ubitrack_agent.io.provider import EdgeAnnouncement, Provider
from ubitrack_agent.net import config
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.session import open_session
from ubitrack_agent.services.handover import Watch

pytestmark = pytest.mark.integration

KEY = KeySpace("ubitrack/watch").data("c-1/AC")
MS = 1_000_000


def error_pose(t_ns: int, variance: float) -> ErrorPose:
    return ErrorPose(t_ns, [0.0, 0.0, 0.0, 1.0], [1.0, 0.0, 0.0], np.eye(6) * variance)


@pytest.fixture
def sessions():
    """A hub session and a container's session linked to it."""
    port = free_port()
    hub = hub_session(port)
    container = open_session(
        config.Settings(connect=(f"tcp/127.0.0.1:{port}",), listen=("tcp/127.0.0.1:0",))
    )
    try:
        yield hub, container
    finally:
        container.close()
        hub.close()


def offer(watch: Watch, publisher, value: ErrorPose) -> bool:
    """What a worker does with its output on a relation key (``Worker._put_outside_held``):
    admitted by the rules, put by the watch; whether it was put at once."""
    payload = encode(value)

    def put() -> None:
        watch.put(publisher.put, payload, value)

    if watch.rules.admit(value, put):
        put()
        return True
    return False


def holding(holder: Watch, watches, publisher, outside: Collector) -> Iterator[int]:
    """Once every watch knows who holds the key, ``holder`` puts until zenoh routes its samples
    to ``outside`` (another session); the timestamps left to put after those, 1 ms apart."""
    wait_until(lambda: not any(w.rules.asking for w in watches), timeout=5)
    start = 1_000_000 * MS
    stamps = iter(range(start, start + 1_000 * MS, MS))
    wait_until(
        lambda: (
            offer(holder, publisher, error_pose(next(stamps), 1e-6)) and not outside.items.empty()
        ),
        interval=0.05,
    )
    return stamps


def counted(observe, into: list[int]):
    """``observe`` (a producer's ``observe_value``) recording each sample's timestamp."""

    def recording(value, latest: bool = False) -> None:
        into.append(value.timestamp_ns)
        observe(value, latest)

    return recording


def test_producers_in_one_process_see_each_others_samples_and_not_their_own(sessions):
    hub, container = sessions
    counters: dict[str, Counter[str]] = {name: Counter() for name in ("a", "b", "remote")}
    a = Watch(container, KEY, counters["a"])
    b = Watch(container, KEY, counters["b"])
    remote = Watch(hub, KEY, counters["remote"])
    publisher = container.declare_publisher(KEY)
    outside = Collector(hub, KEY)
    watches = (a, b, remote)
    seen: dict[str, list[int]] = {"a": [], "b": [], "remote": []}
    for watch, name in ((a, "a"), (b, "b"), (remote, "remote")):
        watch.rules.observe_value = counted(watch.rules.observe_value, seen[name])
    try:
        stamps = holding(a, watches, publisher, outside)
        assert a.rules.holds
        # A less certain producer that has just seen A's sample holds back: the one in the
        # same process (shown it by A's put) as the one in another process (by zenoh).
        for watch, name in ((b, "b"), (remote, "remote")):
            t = next(stamps)
            assert offer(a, publisher, error_pose(t, 1e-6))
            wait_until(lambda t=t, name=name: t in seen[name], timeout=5)
            assert not offer(watch, publisher, error_pose(t + MS // 2, 1.0))
            assert counters[name]["relation_held"] == 1, (name, counters[name])
        # A's samples never came back to A.
        assert seen["a"] == [], seen["a"]
    finally:
        outside.subscriber.undeclare()
        publisher.undeclare()
        for watch in watches:
            watch.close()


@dataclass
class HolderBeside:
    """A holder of the key on the container's session, watching the tokens it needs, and a
    producer beside it on the hub's (another process, as far as zenoh is concerned), with their
    publishers, a collector of the key outside, and the timestamps the one beside has seen."""

    holder: Watch
    beside: Watch
    publisher: Any
    beside_publisher: Any
    outside: Collector
    counters: dict[str, Counter[str]]
    seen: list[int] = field(default_factory=list)

    def held_beside(self) -> tuple[int, Iterator[int]]:
        """The holder puts; the one beside holds back a less certain sample after it: its
        timestamp, and the stamps left to put."""
        stamps = holding(self.holder, (self.holder, self.beside), self.publisher, self.outside)
        t = next(stamps)
        assert offer(self.holder, self.publisher, error_pose(t, 1e-6))
        wait_until(lambda: t in self.seen, timeout=5)
        held = t + MS // 2
        assert not offer(self.beside, self.beside_publisher, error_pose(held, 1.0))
        assert self.counters["beside"]["relation_held"] == 1
        return held, stamps


@contextlib.contextmanager
def holder_beside(hub, container, needed: tuple[str, ...]) -> Iterator[HolderBeside]:
    counters: dict[str, Counter[str]] = {"holder": Counter(), "beside": Counter()}
    pair = HolderBeside(
        Watch(container, KEY, counters["holder"], needed),
        Watch(hub, KEY, counters["beside"]),
        container.declare_publisher(KEY),
        hub.declare_publisher(KEY),
        Collector(hub, KEY),
        counters,
    )
    pair.beside.rules.observe_value = counted(pair.beside.rules.observe_value, pair.seen)
    try:
        yield pair
    finally:
        pair.outside.subscriber.undeclare()
        pair.publisher.undeclare()
        pair.beside_publisher.undeclare()
        pair.holder.close()
        pair.beside.close()


def test_a_holder_gives_the_key_up_when_a_provider_it_needs_leaves(sessions):
    """Rule 7 on real sessions: the holder watches the token of the provider it needs, declared
    before the holder began (as a tracker announced before the agent planned); when the token
    leaves, the producer waiting beside it (another process) puts its sample held back, with
    no further sample of either."""
    hub, container = sessions
    space = KeySpace("ubitrack/watch")
    token = hub.liveliness().declare_token(space.provider("tracker"))
    on_key: list[int] = []
    with holder_beside(hub, container, (space.provider("tracker"),)) as pair:

        def put_on_key(t_ns: int) -> bool:
            while not pair.outside.items.empty():
                on_key.append(decode(pair.outside.items.get_nowait()).timestamp_ns)
            return t_ns in on_key

        held, _ = pair.held_beside()
        token.undeclare()
        wait_until(lambda: pair.counters["beside"]["relation_put_when_free"] == 1, timeout=5)
        assert pair.counters["holder"]["relation_given_up"] == 1
        assert pair.counters["beside"]["relation_holder_gave_up"] == 1
        assert pair.beside.rules.holds and not pair.holder.rules.holds
        wait_until(lambda: put_on_key(held), timeout=5)
        assert not offer(pair.holder, pair.publisher, error_pose(held + MS, 1e-6))  # late


def test_a_holder_gives_the_key_up_when_an_edge_it_needs_falls_silent_and_takes_it_back(sessions):
    """Rule 7 for an edge whose provider runs on (a tracker switched off, its adapter alive):
    a real provider's token on the edge's data key leaves two and a half of its intervals
    after its last sample (``io.flowing``), the holder gives the key up to the producer beside
    it; the edge's next sample declares the token again, and the holder's next estimate, no
    less certain, takes the key back (rule 6) with no quiet time to wait."""
    hub, container = sessions
    space = KeySpace("ubitrack/watch")
    tracker = Provider(hub, space, "tracker", [EdgeAnnouncement("ART", "HT", "6D", rate=60.0)])

    def track(count: int) -> None:
        for _ in range(count):
            tracker.publish("ART_HT", error_pose(time.time_ns(), 1e-6))
            time.sleep(1 / 60)

    try:
        track(2)  # the edge flows before the holder is watching (its token declared)
        with holder_beside(hub, container, (space.measured("tracker", "ART_HT"),)) as pair:
            _, stamps = pair.held_beside()
            track(6)  # its rate known, then silent: the token leaves 2.5 intervals later
            counters = pair.counters
            wait_until(lambda: counters["beside"]["relation_put_when_free"] == 1, timeout=5)
            assert counters["holder"]["relation_given_up"] == 1
            assert pair.beside.rules.holds and not pair.holder.rules.holds
            assert offer(pair.beside, pair.beside_publisher, error_pose(next(stamps), 1.0))
            track(1)  # the tracker is back
            wait_until(lambda: counters["holder"]["relation_input_back"] == 1, timeout=5)
            # claims it back
            assert not offer(pair.holder, pair.publisher, error_pose(next(stamps), 1e-6))
            wait_until(lambda: pair.holder.rules.holds, timeout=5)
            assert counters["holder"]["relation_taken_back"] == 1
            assert not pair.beside.rules.holds
    finally:
        tracker.close()
