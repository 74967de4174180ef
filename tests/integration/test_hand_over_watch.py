"""The hand-over watch of a relation key (``ubitrack_agent.services.handover.Watch``) on real
zenoh sessions: its subscriber takes only other processes' samples (``Locality.REMOTE``), so a
producer's own puts do not come back to it, and the other producers of the key in the same
process are shown its samples by ``Watch.put``. Real sessions on loopback: a hub (another
process's session, as far as zenoh is concerned) and a container's session with two
producers of one key."""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator

import numpy as np
import pytest

from tests.integration.zenoh_helpers import Collector, free_port, hub_session, wait_until
from ubitrack_agent.core import ErrorPose, decode, encode
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


def test_a_holder_gives_the_key_up_when_a_provider_it_needs_leaves(sessions):
    """Rule 7 on real sessions: the holder watches the token of the provider it needs, declared
    before the holder began (as a tracker announced before the agent planned); when the token
    leaves, the producer waiting beside it (another process) puts its sample held back, with
    no further sample of either."""
    hub, container = sessions
    space = KeySpace("ubitrack/watch")
    token = hub.liveliness().declare_token(space.provider("tracker"))
    counters: dict[str, Counter[str]] = {"holder": Counter(), "beside": Counter()}
    holder = Watch(container, KEY, counters["holder"], (space.provider("tracker"),))
    beside = Watch(hub, KEY, counters["beside"])
    publisher = container.declare_publisher(KEY)
    beside_publisher = hub.declare_publisher(KEY)
    outside = Collector(hub, KEY)
    watches = (holder, beside)
    seen: list[int] = []
    beside.rules.observe_value = counted(beside.rules.observe_value, seen)
    on_key: list[int] = []

    def put_on_key(t_ns: int) -> bool:
        while not outside.items.empty():
            on_key.append(decode(outside.items.get_nowait()).timestamp_ns)
        return t_ns in on_key

    try:
        stamps = holding(holder, watches, publisher, outside)
        t = next(stamps)
        assert offer(holder, publisher, error_pose(t, 1e-6))
        wait_until(lambda: t in seen, timeout=5)
        held = t + MS // 2
        assert not offer(beside, beside_publisher, error_pose(held, 1.0))  # less certain
        assert counters["beside"]["relation_held"] == 1
        token.undeclare()
        wait_until(lambda: counters["beside"]["relation_put_when_free"] == 1, timeout=5)
        assert counters["holder"]["relation_given_up"] == 1
        assert counters["beside"]["relation_holder_gave_up"] == 1
        assert beside.rules.holds and not holder.rules.holds
        wait_until(lambda: put_on_key(held), timeout=5)
        assert not offer(holder, publisher, error_pose(held + MS, 1e-6))  # its last, late
    finally:
        outside.subscriber.undeclare()
        publisher.undeclare()
        beside_publisher.undeclare()
        for watch in watches:
            watch.close()
