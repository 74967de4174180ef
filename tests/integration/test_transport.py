"""``net.transport.subscribe_in_bursts`` between two real zenoh sessions on loopback: every
sample handed on once and in order, a backlog as bursts, and its thread gone once the
subscriber is undeclared."""

from __future__ import annotations

import threading
import time

import zenoh

from tests.integration.zenoh_helpers import free_port, hub_session, wait_until
from ubitrack_agent.net import config
from ubitrack_agent.net.session import open_session
from ubitrack_agent.net.transport import INPUT_CHANNEL_CAPACITY, subscribe_in_bursts


def test_a_backlog_is_handed_on_whole_in_order_and_the_thread_ends_with_the_subscriber():
    port = free_port()
    member = config.Settings(connect=(f"tcp/127.0.0.1:{port}",), listen=("tcp/127.0.0.1:0",))
    handed: list[bytes] = []
    bursts: list[int] = []
    threads: set[int] = set()
    first = threading.Event()

    def deliver(payloads: list[bytes]) -> None:
        threads.add(threading.get_ident())
        if not first.is_set():
            first.set()
            time.sleep(0.2)  # a backlog builds in zenoh's channel meanwhile
        bursts.append(len(payloads))
        handed.extend(payloads)

    with hub_session(port) as hub, open_session(member) as session:
        subscriber = subscribe_in_bursts(session, "test/bursts", deliver)
        publisher = hub.declare_publisher(
            "test/bursts", congestion_control=zenoh.CongestionControl.BLOCK
        )
        wait_until(lambda: publisher.matching_status.matching)
        sent = [b"%d" % i for i in range(3000)]
        for payload in sent:
            publisher.put(payload)
        wait_until(lambda: len(handed) >= len(sent))
        assert handed == sent and len(threads) == 1
        assert max(bursts) > 1 and max(bursts) <= INPUT_CHANNEL_CAPACITY  # the backlog at once
        drains = [t for t in threading.enumerate() if t.name == "input test/bursts"]
        assert len(drains) == 1
        subscriber.undeclare()
        drains[0].join(timeout=5.0)
        assert not drains[0].is_alive()
        publisher.put(b"after")
        time.sleep(0.2)
        assert handed[-1] == sent[-1]


def test_undeclaring_while_a_burst_is_drained_ends_the_thread_quietly(monkeypatch):
    """A rewire undeclares an input's subscriber while its thread drains a burst: the thread
    ends without an exception (a call on the subscriber itself failed then: "Already mutably
    borrowed", seen in a demo run)."""
    raised: list[BaseException] = []
    monkeypatch.setattr(threading, "excepthook", lambda args: raised.append(args.exc_value))
    port = free_port()
    member = config.Settings(connect=(f"tcp/127.0.0.1:{port}",), listen=("tcp/127.0.0.1:0",))
    with hub_session(port) as hub, open_session(member) as session:
        publisher = hub.declare_publisher("test/undeclare")
        stop = threading.Event()

        def flood() -> None:
            while not stop.is_set():
                publisher.put(b"x")

        for attempt in range(20):
            handed: list[bytes] = []
            subscriber = subscribe_in_bursts(session, "test/undeclare", handed.extend)
            wait_until(lambda: publisher.matching_status.matching)
            if attempt == 0:
                flooding = threading.Thread(target=flood, daemon=True)
                flooding.start()
            wait_until(lambda handed=handed: len(handed) > 100)
            subscriber.undeclare()
            for thread in threading.enumerate():
                if thread.name == "input test/undeclare":
                    thread.join(timeout=5.0)
                    assert not thread.is_alive()
        stop.set()
        flooding.join(timeout=5.0)
    assert raised == []
