"""``net.transport.subscribe_in_bursts`` between two real zenoh sessions on loopback: every
sample handed on once and in order, a backlog included, and its thread gone once the
subscriber is undeclared."""

from __future__ import annotations

import threading
import time

import zenoh

from tests.integration.zenoh_helpers import free_port, hub_session, wait_until
from ubitrack_agent.net import config
from ubitrack_agent.net.session import open_session
from ubitrack_agent.net.transport import subscribe_in_bursts


def test_a_backlog_is_handed_on_whole_in_order_and_the_thread_ends_with_the_subscriber():
    port = free_port()
    member = config.Settings(connect=(f"tcp/127.0.0.1:{port}",), listen=("tcp/127.0.0.1:0",))
    handed: list[bytes] = []
    threads: set[int] = set()
    first = threading.Event()

    def deliver(payload: bytes) -> None:
        threads.add(threading.get_ident())
        if not first.is_set():
            first.set()
            time.sleep(0.2)  # a backlog builds in zenoh's channel meanwhile
        handed.append(payload)

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
        drains = [t for t in threading.enumerate() if t.name == "input test/bursts"]
        assert len(drains) == 1
        subscriber.undeclare()
        drains[0].join(timeout=5.0)
        assert not drains[0].is_alive()
        publisher.put(b"after")
        time.sleep(0.2)
        assert handed[-1] == sent[-1]
