"""``net.transport`` between two real zenoh sessions on loopback: ``subscribe_in_bursts`` hands
every sample on once and in order, a backlog as bursts, and its thread is gone once the
subscriber is undeclared; ``LatestValuePublisher`` answers queries on shared threads."""

from __future__ import annotations

import threading
import time

import pytest
import zenoh

from tests.integration.zenoh_helpers import free_port, hub_session, wait_until
from ubitrack_agent.core.errors import ExtrapolationError
from ubitrack_agent.net import config
from ubitrack_agent.net.session import open_session
from ubitrack_agent.net.time_queries import fetch_at, raise_error, selector
from ubitrack_agent.net.transport import (
    ANSWERING_THREADS,
    INPUT_CHANNEL_CAPACITY,
    LatestValuePublisher,
    fetch_latest,
    subscribe_in_bursts,
)


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


def test_a_time_query_is_answered_while_another_keys_answer_waits_or_fails():
    """Publishers share the process's answering threads (``net.transport.ANSWERS``) and start
    none of their own: while one key's ``at`` is still computing (then fails unexpectedly:
    counted, the query left unanswered), another key's time query, its latest value and a
    third key's typed refusal are answered; a hostile time is refused and counted."""
    port = free_port()
    member = config.Settings(connect=(f"tcp/127.0.0.1:{port}",), listen=("tcp/127.0.0.1:0",))
    release = threading.Event()
    entered = threading.Event()

    def stuck(t: int) -> bytes:
        entered.set()
        release.wait(timeout=10.0)
        raise RuntimeError("a bug in the answer")

    def refuses(t: int) -> bytes:
        raise ExtrapolationError("beyond the motion model")

    with hub_session(port) as asker, open_session(member) as session:
        before = {thread.ident for thread in threading.enumerate()}
        slow = LatestValuePublisher(session, "test/at/slow", stuck)
        fine = LatestValuePublisher(session, "test/at/fine", lambda t: b"%d" % t)
        far = LatestValuePublisher(session, "test/at/far", refuses)
        more = [LatestValuePublisher(session, f"test/at/more/{k}") for k in range(50)]
        assert {thread.ident for thread in threading.enumerate()} <= before  # none started
        fine.put(b"latest")
        wait_until(lambda: fetch_latest(asker, "test/at/fine") == [b"latest"])
        waiting = threading.Thread(
            target=lambda: list(asker.get(selector("test/at/slow", 5), timeout=10.0))
        )
        waiting.start()
        assert entered.wait(timeout=5.0)
        assert fetch_at(asker, "test/at/fine", 7, timeout=2.0) == b"7"
        assert fetch_latest(asker, "test/at/fine") == [b"latest"]
        with pytest.raises(ExtrapolationError, match="motion model"):
            fetch_at(asker, "test/at/far", 7, timeout=2.0)
        with pytest.raises(ValueError, match="integer nanoseconds"):
            for reply in asker.get("test/at/fine?t=soon", timeout=2.0):
                raise_error(reply.err.payload.to_bytes(), "test/at/fine")
        assert waiting.is_alive()  # slow's at still runs
        release.set()
        waiting.join(timeout=10.0)
        wait_until(lambda: slow.counters["internal_errors"] == 1)
        assert fine.counters["rejected_queries"] == 1 and fine.counters["internal_errors"] == 0
        assert fetch_at(asker, "test/at/fine", 9, timeout=2.0) == b"9"  # and the next
        answering = [t for t in threading.enumerate() if t.name.startswith("answers")]
        assert 2 <= len(answering) <= ANSWERING_THREADS
        for publisher in (slow, fine, far, *more):
            publisher.undeclare()


def test_a_publisher_undeclared_while_another_thread_puts_closes_quietly():
    """A worker rewires its outputs (undeclares a publisher) on its control thread while its
    data thread puts on that publisher: zenoh's publisher refuses to be undeclared during a put
    ("Already borrowed", found by the chaos bench). The undeclare leaves the publisher to the
    put running, which undeclares it when done (no thread waits for another's zenoh call: a
    worker thread waiting there stopped answering its status); a put after it is dropped."""
    port = free_port()
    member = config.Settings(connect=(f"tcp/127.0.0.1:{port}",), listen=("tcp/127.0.0.1:0",))
    with hub_session(port) as hub, open_session(member) as session:
        received: list[bytes] = []
        listener = hub.declare_subscriber("test/race/**", lambda s: received.append(b""))
        raised: list[BaseException] = []
        for round_ in range(20):
            publisher = LatestValuePublisher(session, f"test/race/{round_}")
            stop = threading.Event()

            def flood(publisher=publisher, stop=stop) -> None:
                try:
                    while not stop.is_set():
                        publisher.put(b"x" * 64)
                except Exception as exc:  # what the put raised is the finding
                    raised.append(exc)

            flooding = threading.Thread(target=flood)
            flooding.start()
            time.sleep(0.01)
            try:
                publisher.undeclare()
            except RuntimeError as exc:
                raised.append(exc)
            stop.set()
            flooding.join(timeout=5.0)
        listener.undeclare()
    assert received, "no sample reached the hub: the puts did not run"
    assert raised == []
