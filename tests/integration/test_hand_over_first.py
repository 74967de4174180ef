"""A component of a container hands its output to the readers in its process first and puts it
on zenoh for the readers outside after (``ubitrack_agent.services.worker``, ``Worker._publish``):
the flow in the container does not wait for zenoh. Where two threads publish one output (the
asynchronous fusion's two inputs, each on its own thread), its samples leave in the order they were
published, never an older one after a newer one. Real zenoh sessions on loopback (a hub and
the container's session), real threads; the reader in the container is a local wire's
(``ubitrack_agent.services.local_wires``)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from tests.integration.zenoh_helpers import Collector, free_port, hub_session, wait_until
from ubitrack_agent.core import ErrorPose, decode, encode
from ubitrack_agent.net import config
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.session import open_session
from ubitrack_agent.net.spec import ComponentSpec, InputBinding
from ubitrack_agent.services.local_wires import LocalWires
from ubitrack_agent.services.worker import Worker

pytestmark = pytest.mark.integration

KEYS = KeySpace("ubitrack/handover")
FUSED = KEYS.data("fuse/fused")
FUSION = ComponentSpec(
    instance="fuse",
    service="fusion",  # asynchronous: each estimate published at once, on its input's thread
    inputs=tuple(InputBinding("AB", KEYS.data(f"T{i}/AB"), trigger=True) for i in range(2)),
    outputs={"fused": FUSED},
    expansion="space",
)
MS = 1_000_000


def error_pose(t_ns: int) -> bytes:
    return encode(ErrorPose(t_ns, [0.0, 0.0, 0.0, 1.0], [1.0, 0.0, 0.0], np.eye(6) * 1e-6))


class SlowReader:
    """A reader in the container: records each value handed to it and, for the timestamps
    in :attr:`hold`, runs the check given there before it returns (holding the producer's
    thread, as a long chain downstream would)."""

    def __init__(self) -> None:
        self.taken: list[int] = []
        self.entered: dict[int, threading.Event] = {}
        self.hold: dict[int, object] = {}

    def deliver(self, values) -> None:
        for value in values:
            t = value.timestamp_ns
            self.taken.append(t)
            self.entered.setdefault(t, threading.Event()).set()
            if (check := self.hold.get(t)) is not None:
                check()


@pytest.fixture
def fusion_in_a_container():
    """The fusion running in a container's session with a reader in the container and one
    outside (on the hub) of its output; providers of its two inputs on the hub."""
    port = free_port()
    hub = hub_session(port)
    session = open_session(
        config.Settings(connect=(f"tcp/127.0.0.1:{port}",), listen=("tcp/127.0.0.1:0",))
    )
    wires = LocalWires()
    reader = SlowReader()
    wires.subscribe(FUSED, reader.deliver)
    worker = Worker(FUSION, session, KEYS, wires=wires, container="c0")
    thread = threading.Thread(target=worker.run, daemon=True)
    thread.start()
    outside = Collector(hub, FUSED)
    providers = [hub.declare_publisher(KEYS.data(f"T{i}/AB")) for i in range(2)]
    try:
        warm_up = time.time_ns() - 2_000 * MS
        stamps = iter(range(warm_up, warm_up + 1_000 * MS, MS))
        # Until zenoh routes both ways: warm-up samples until one reaches the hub.
        wait_until(
            lambda: providers[0].put(error_pose(next(stamps))) or not outside.items.empty(),
            interval=0.05,
        )
        time.sleep(0.2)
        outside.drain()
        yield worker, reader, outside, providers, warm_up + 1_000 * MS
    finally:
        worker.stop()
        thread.join(timeout=5)
        for provider in providers:
            provider.undeclare()
        outside.subscriber.undeclare()
        session.close()
        hub.close()
    assert not thread.is_alive()


def received(outside: Collector) -> list[int]:
    out = []
    while not outside.items.empty():
        out.append(decode(outside.items.get_nowait()).timestamp_ns)
    return out


def test_the_reader_in_the_container_has_the_value_before_zenoh_carries_it(
    fusion_in_a_container,
):
    worker, reader, outside, providers, start = fusion_in_a_container
    before = dict(worker.counters)
    t = start + 10 * MS
    seen_outside = []
    # While the reader in the container holds the value, nothing has left for the hub.
    reader.hold[t] = lambda: seen_outside.append(wait_for_item(outside, 0.5))
    providers[0].put(error_pose(t))
    wait_until(lambda: seen_outside)
    assert seen_outside == [False]
    assert decode(outside.next()).timestamp_ns == t  # then zenoh carried it
    counters = worker.counters
    assert counters["published"] - before["published"] == 1
    assert counters["handed_over"] - before["handed_over"] == 1
    assert counters["not_sent"] == before["not_sent"]


def wait_for_item(outside: Collector, timeout: float) -> bool:
    """Whether something reached the collector within ``timeout`` (left queued)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if not outside.items.empty():
            return True
        time.sleep(0.005)
    return False


def test_two_threads_publishing_one_output_keep_its_order_on_zenoh(fusion_in_a_container):
    worker, reader, outside, providers, start = fusion_in_a_container
    before = dict(worker.counters)
    older, newer = start + 20 * MS, start + 30 * MS
    # The first input's thread holds the older value in the container (its hand-over not
    # returned, its put not made) until the hub has the newer one, which the second input's
    # thread published meanwhile; or for 3 s.
    outside_order: list[int] = []

    def until_newer_outside() -> None:
        deadline = time.monotonic() + 3.0
        while newer not in outside_order and time.monotonic() < deadline:
            outside_order.extend(received(outside))
            time.sleep(0.005)

    reader.hold[older] = until_newer_outside
    providers[0].put(error_pose(older))
    assert reader.entered.setdefault(older, threading.Event()).wait(5)
    providers[1].put(error_pose(newer))
    wait_until(lambda: newer in reader.taken)
    wait_until(lambda: newer in outside_order)
    time.sleep(0.1)  # anything put after the held reader returned
    outside_order.extend(received(outside))
    assert outside_order == [older, newer]
    assert reader.taken[-2:] == [older, newer]
    counters = worker.counters
    assert counters["published"] - before["published"] == 2
    assert counters["handed_over"] - before["handed_over"] == 2
    assert counters["not_sent"] == before["not_sent"]
