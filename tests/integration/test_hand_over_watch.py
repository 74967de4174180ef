"""The hand-over watch of a relation key (``ubitrack_agent.services.handover.Watch``) on real
zenoh sessions: its subscriber takes only other processes' samples (``Locality.REMOTE``), so a
producer's own puts do not come back to it, and the other producers of the key in the same
process are shown its samples by ``Watch.put``. Real sessions on loopback: a hub (another
process's session, as far as zenoh is concerned) and a container's session with two
producers of one key."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from tests.integration.zenoh_helpers import Collector, free_port, hub_session, wait_until
from ubitrack_agent.core import ErrorPose, encode
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
        wait_until(lambda: not any(w.rules.asking for w in watches), timeout=5)
        start = 1_000_000 * MS
        stamps = iter(range(start, start + 1_000 * MS, MS))
        # Until zenoh routes from the container to the hub.
        wait_until(
            lambda: (
                offer(a, publisher, error_pose(next(stamps), 1e-6)) and not outside.items.empty()
            ),
            interval=0.05,
        )
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
