"""The worker's handling of network input (``services/worker.py``, issue 11) on a stand-in
session: every sample, control command and pool specification is used or rejected with a
named counter, and nothing raises out of a handler."""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import deque
from types import SimpleNamespace

import msgpack
import numpy as np
import pytest
import zenoh

from ubitrack_agent.core import ErrorPose, Pose, Position3D, decode, encode
from ubitrack_agent.core.timeline import MAX_FUTURE_NS
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.spec import ComponentSpec, GroupSpec, InputBinding
from ubitrack_agent.services.worker import COUNTERS, MAX_HELD_FOR_STATIC, Pool, Worker

KEYS = KeySpace("ubitrack/test")
IDENTITY = [0.0, 0.0, 0.0, 1.0]


class FakeQueryable(list):
    """No query arrives."""

    def undeclare(self) -> None:
        pass


class FakeChannel:
    """A subscriber with zenoh's ``FifoChannel`` handler, as ``net.transport``'s
    ``subscribe_in_bursts`` declares one. :meth:`push_burst` puts its samples in at once, so the
    thread draining it takes them as one burst, and returns once that thread has handled them
    (it waits for the next sample then): a test that delivers a sample finds it handled."""

    def __init__(self, on_undeclare) -> None:
        self._changed = threading.Condition()
        self._items: deque = deque()
        self._closed = False
        self._taken: list[threading.Event] = []
        self._on_undeclare = on_undeclare

    @property
    def handler(self) -> FakeChannel:
        return self

    def push_burst(self, samples, wait: bool = True) -> None:
        handled = [threading.Event() for _ in samples]
        with self._changed:
            self._items.extend(zip(samples, handled, strict=True))
            self._changed.notify()
        if wait and not all(event.wait(5.0) for event in handled):
            raise TimeoutError("the subscription's thread did not handle the samples")

    def __iter__(self):
        return self

    def __next__(self):
        for event in self._taken:  # the burst taken before is handled
            event.set()
        self._taken = []
        with self._changed:
            self._changed.wait_for(lambda: self._items or self._closed)
            if not self._items:
                raise StopIteration
            sample, handled = self._items.popleft()
        self._taken.append(handled)
        return sample

    def try_recv(self):
        with self._changed:
            if not self._items:
                return None
            sample, handled = self._items.popleft()
        self._taken.append(handled)
        return sample

    def undeclare(self) -> None:
        self._on_undeclare()
        with self._changed:
            self._closed = True
            self._changed.notify()


class FakeSession:
    """Records subscriptions and puts; answers no query."""

    def __init__(self) -> None:
        self.callbacks: dict[str, object] = {}
        self.channels: dict[str, FakeChannel] = {}
        self.puts: list[tuple[str, bytes]] = []
        self.encodings: dict[str, object] = {}
        self.congestion: dict[str, object] = {}

    def declare_subscriber(self, key, callback, allowed_origin=None):
        """A subscriber (``allowed_origin``: a hand-over watch's, its session's own puts
        not delivered; this session delivers none of its puts anyway)."""
        if isinstance(callback, zenoh.handlers.FifoChannel):
            channel = self.channels[key] = FakeChannel(lambda: self.channels.pop(key, None))
            return channel
        self.callbacks[key] = callback
        return SimpleNamespace(undeclare=lambda: self.callbacks.pop(key, None))

    def declare_publisher(self, key, encoding=None, congestion_control=None):
        """A publisher with a subscriber listening (zenoh's matching status): it puts."""
        self.encodings[key] = encoding
        self.congestion[key] = congestion_control
        return SimpleNamespace(
            put=lambda data, attachment=None: self.puts.append((key, data)),
            undeclare=lambda: None,
            matching_status=SimpleNamespace(matching=True),
            declare_matching_listener=lambda callback: SimpleNamespace(undeclare=lambda: None),
        )

    def declare_queryable(self, key, handler=None):
        return FakeQueryable()

    def liveliness(self):
        return SimpleNamespace(
            declare_token=lambda key: SimpleNamespace(undeclare=lambda: None),
            declare_subscriber=lambda key, callback, history=False: self.declare_subscriber(
                key, callback
            ),
        )

    def get(self, key, handler=None, timeout=None):
        return None if handler is not None else []

    def deliver(self, key: str, payload: bytes, wait: bool = True) -> None:
        """What zenoh does when ``payload`` arrives on ``key``; for an input of a worker
        (``subscribe_in_bursts``), returning once its thread has handled it, unless not
        ``wait``."""
        if key in self.channels:
            self.deliver_burst(key, [payload], wait)
        else:
            self.callbacks[key](zenoh_sample(payload))

    def deliver_burst(self, key: str, payloads: list[bytes], wait: bool = True) -> None:
        """``payloads`` arriving on the input ``key`` together, taken by its thread as one
        burst; returns once it has handled them, unless not ``wait``."""
        self.channels[key].push_burst([zenoh_sample(payload) for payload in payloads], wait)


def zenoh_sample(payload: bytes) -> SimpleNamespace:
    return SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: payload), attachment=None)


SPEC = ComponentSpec(
    instance="concat1",
    service="concatenation",
    inputs=(
        InputBinding("AB", KEYS.data("ART/WT"), static=True),
        InputBinding("BC", KEYS.data("ART/HT"), trigger=True),
    ),
    outputs={"AC": KEYS.data("concat1/AC")},
)


@pytest.fixture
def worker():
    session = FakeSession()
    worker = Worker(SPEC, session, KEYS)
    yield worker, session
    worker.stop()


def feed(worker: Worker, session: FakeSession, key: str, payload: bytes) -> None:
    session.deliver(key, payload)
    worker.step(longest_s=0.0)


def outputs(session: FakeSession) -> list[Pose]:
    return [decode(data) for key, data in session.puts if key == KEYS.data("concat1/AC")]


def pose(t: int, x: float = 1.0) -> bytes:
    return encode(Pose(t, IDENTITY, [x, 0.0, 0.0]))


def test_status_shows_every_counter(worker):
    w, _ = worker
    assert set(w.status()["counters"]) == set(COUNTERS)


def test_a_pose_stamped_a_day_ahead_is_rejected_and_never_stalls_the_relation(worker):
    """Regression: one valid pose a day ahead stopped the relation until the worker restarted
    (received rising, published flat, nothing counted)."""
    w, session = worker
    now = time.time_ns()
    feed(w, session, KEYS.data("ART/WT"), pose(now, 0.5))
    feed(w, session, KEYS.data("ART/HT"), pose(now + 86_400 * 10**9))
    assert w.counters["rejected_future"] == 1
    for i in range(1, 4):
        feed(w, session, KEYS.data("ART/HT"), pose(now + i * 1_000_000))
    results = outputs(session)
    assert [r.timestamp_ns for r in results] == [now + i * 1_000_000 for i in (1, 2, 3)]
    np.testing.assert_allclose(results[-1].translation, [1.5, 0.0, 0.0])


def test_a_sample_just_within_the_bound_is_used(worker):
    w, session = worker
    now = time.time_ns()
    feed(w, session, KEYS.data("ART/WT"), pose(now))
    feed(w, session, KEYS.data("ART/HT"), pose(now + MAX_FUTURE_NS // 2))
    assert w.counters["rejected_future"] == 0 and len(outputs(session)) == 1


def test_a_pose_with_six_translation_values_is_rejected(worker):
    """Regression: the codec raised ValueError from reshape, which killed the worker."""
    w, session = worker
    message = msgpack.unpackb(pose(time.time_ns()))
    message["translation"] = np.zeros(6).tobytes()
    feed(w, session, KEYS.data("ART/HT"), msgpack.packb(message))
    assert w.counters["rejected"] == 1 and w.counters["internal_errors"] == 0


def test_every_sample_consumed_without_output_is_counted(worker):
    w, session = worker
    now = time.time_ns()
    feed(w, session, KEYS.data("ART/HT"), pose(now))  # no static value yet: held
    w.step(longest_s=0.0)
    feed(w, session, KEYS.data("ART/WT"), pose(now))  # a static input, not a trigger
    feed(w, session, KEYS.data("ART/HT"), pose(now))  # the instant already computed
    feed(w, session, KEYS.data("ART/HT"), pose(now + 1))
    c = w.counters
    assert (c["received"], c["held_for_static"], c["buffered"], c["stale_triggers"]) == (4, 1, 1, 1)
    assert c["dropped"] == 0 and c["published"] == 2


def test_triggers_before_the_static_value_are_computed_with_it_in_order(worker):
    """Issue [seamless]: a flow's first samples are not lost while a static edge it composes
    with is still on its way; at most MAX_HELD_FOR_STATIC wait."""
    w, session = worker
    now = time.time_ns()
    for i in range(MAX_HELD_FOR_STATIC + 3):
        feed(w, session, KEYS.data("ART/HT"), pose(now + i, x=float(i)))
    assert outputs(session) == [] and w.counters["dropped"] == 3  # the oldest three
    feed(w, session, KEYS.data("ART/WT"), pose(now, 0.5))
    results = outputs(session)
    assert [r.timestamp_ns for r in results] == [now + i for i in range(3, MAX_HELD_FOR_STATIC + 3)]
    np.testing.assert_allclose(results[0].translation, [3.5, 0.0, 0.0])
    assert w.counters["held_for_static"] == MAX_HELD_FOR_STATIC + 3


def test_a_sample_older_than_its_buffer_is_counted(worker):
    w, session = worker
    now = time.time_ns()
    for i in range(1, 70):  # a full buffer: 64 samples
        feed(w, session, KEYS.data("ART/HT"), pose(now + i))
    feed(w, session, KEYS.data("ART/HT"), pose(now - 10**9))
    assert w.counters["dropped_stale"] == 1


@pytest.mark.parametrize(
    "payload, reason",
    [
        (b"[" * 100_000 + b"]" * 100_000, "not JSON or nested"),  # RecursionError before
        (json.dumps({"inputs": 1}).encode(), "inputs"),
        ((b'{"parameters": ' + b"[" * 40 + b"]" * 40 + b"}"), "nested"),
        (b"\xff\xfe", "not UTF-8"),
        (json.dumps({"stop": "yes"}).encode(), "stop"),
        (json.dumps({"stop": 1}).encode(), "stop"),  # 1 == True in Python, not in JSON
        (json.dumps({"stop": True, "inputs": []}).encode(), "stop"),
        (json.dumps({"parameters": {"nope": 1}}).encode(), "unknown parameters"),
        (json.dumps({"outputs": {"AC": KEYS.data("x/AC")}}).encode(), "output keys are fixed"),
        (b"{" + b" " * 70_000 + b"}", "oversized"),
    ],
)
def test_a_bad_control_command_is_rejected_and_counted(worker, payload, reason):
    w, session = worker
    feed(w, session, KEYS.control("concat1"), payload)
    assert w.counters["rejected_commands"] == 1
    assert w.counters["internal_errors"] == 0 and w.counters["rewired"] == 0


def test_a_control_command_is_applied_in_full_or_not_at_all(worker):
    w, session = worker
    command = {
        "relations": {"AC": [KEYS.relation(RelationId("C", "A", "6D"))]},
        "inputs": [{"port": "nope", "key": "a"}],
    }
    feed(w, session, KEYS.control("concat1"), json.dumps(command).encode())
    assert w.counters["rejected_commands"] == 1 and w.spec == SPEC


def test_an_unexpected_fault_is_counted_not_raised(worker, monkeypatch):
    w, session = worker

    def broken(*args):
        raise RuntimeError("a bug")

    monkeypatch.setattr(w._service, "compute", broken)
    now = time.time_ns()
    feed(w, session, KEYS.data("ART/WT"), pose(now))
    feed(w, session, KEYS.data("ART/HT"), pose(now))
    assert w.counters["internal_errors"] == 1
    monkeypatch.undo()
    feed(w, session, KEYS.data("ART/HT"), pose(now + 1))
    assert w.counters["published"] == 1


@pytest.mark.parametrize(
    "payload",
    [
        b"[" * 100_000 + b"]" * 100_000,  # RecursionError killed the idle pool worker
        b'{"instance": ' + b"[" * 50 + b"]" * 50 + b"}",
        b"\xff",
        json.dumps({**SPEC.as_dict(), "service": "os.system"}).encode(),
        json.dumps({**SPEC.as_dict(), "parameters": {"x": 1e400}}).encode(),
        json.dumps({**SPEC.as_dict(), "relations": {"AC": ["not/a/relation"]}})[:-1].encode(),
        json.dumps({"container": "c", "components": [{**SPEC.as_dict(), "service": "x"}]}).encode(),
        json.dumps({"container": "c", "components": [SPEC.as_dict()], "x": 1}).encode(),
        json.dumps({"container": "*", "components": []}).encode(),
    ],
)
def test_an_idle_pool_worker_rejects_a_bad_specification_and_keeps_waiting(payload):
    pool = Pool(FakeSession(), KEYS, "p1", SimpleNamespace(when_gone=lambda wake: None))
    assert pool._read_spec(payload) is None
    assert pool.counters["rejected_specs"] == 1
    assert pool._read_spec(SPEC.to_json().encode()) == SPEC
    group = GroupSpec("c", (SPEC,))
    assert pool._read_spec(group.to_json().encode()) == group  # the member becomes a container


def test_a_relation_route_that_is_no_relation_key_does_not_stop_the_worker():
    spec = ComponentSpec(**{**vars(SPEC), "relations": {"AC": ("some/other/key",)}})
    worker = Worker(spec, FakeSession(), KEYS)
    worker.stop()


def test_no_output_waits_for_a_full_link():
    """net.transport, "Nothing waits for a reader": the data key and the relation key an
    application reads both drop on a full link (a stopped reader holds nobody)."""
    relation = KEYS.relation(RelationId("W", "T", "6D"))
    spec = ComponentSpec(**{**vars(SPEC), "relations": {"AC": (relation,)}})
    session = FakeSession()
    worker = Worker(spec, session, KEYS)
    worker.stop()
    assert session.congestion[KEYS.data("concat1/AC")] == zenoh.CongestionControl.DROP
    assert session.congestion[relation] == zenoh.CongestionControl.DROP


FUSION = ComponentSpec(
    instance="fuse",
    service="fusion",
    inputs=tuple(InputBinding("AB", KEYS.data(f"T{i}/AB"), trigger=True) for i in range(2)),
    outputs={"fused": KEYS.data("fuse/fused")},
    expansion="space",
)


def error_pose(t: int, x: float = 1.0, rotation=IDENTITY) -> bytes:
    return encode(ErrorPose(t, rotation, [x, 0.0, 0.0], np.eye(6) * 1e-6))


def test_asynchronous_fusion_counts_every_sample_and_answers_a_time():
    """Each estimate publishes at once or is counted (gated, late, dropped_stale, failed);
    a query for a time is answered by the filter on the query's own thread."""
    session = FakeSession()
    w = Worker(FUSION, session, KEYS)
    now = time.time_ns() - 10**9
    feed(w, session, KEYS.data("T0/AB"), error_pose(now))
    feed(w, session, KEYS.data("T1/AB"), error_pose(now + 10**7))
    feed(w, session, KEYS.data("T0/AB"), error_pose(now + 5 * 10**6))  # late
    flipped = [0.0, 0.0, 1.0, 0.0]
    feed(w, session, KEYS.data("T1/AB"), error_pose(now + 2 * 10**7, rotation=flipped))
    feed(w, session, KEYS.data("T0/AB"), error_pose(now - 10**9))  # beyond the window
    feed(w, session, KEYS.data("T0/AB"), encode(Position3D(now + 3 * 10**7, [0, 0, 0])))
    published = [decode(d) for k, d in session.puts if k == KEYS.data("fuse/fused")]
    assert [p.timestamp_ns for p in published] == [now, now + 10**7]
    counters = w.counters
    assert (counters["late"], counters["gated"], counters["dropped_stale"]) == (1, 1, 1)
    assert counters["failed"] == 1 and counters["received"] == 6
    publisher = w._publishers[KEYS.data("fuse/fused")]
    replies: list[bytes] = []
    query = SimpleNamespace(
        parameters={"t": str(now + 3 * 10**7)},
        reply=lambda key, payload, encoding, attachment=None: replies.append(payload),
        reply_err=lambda payload: replies.append(b"error " + payload),
    )
    publisher._reply(query)
    (reply,) = replies
    assert decode(reply).timestamp_ns == now + 3 * 10**7
    assert w.counters["time_queries"] == 1  # a copy: read again
    w.stop()


def test_the_wiring_a_worker_already_has_resets_no_filter_and_renews_no_subscription():
    """An agent taking over sends each worker its whole wiring (``agent.runtime._adopt``).
    Resent to a running fusion, it changed nothing: before, the filter was rebuilt, and the
    next estimate, older than the last output, reached the application out of time order
    (the rare ``out_of_order`` of ``tests/integration/test_standby.py``). New parameters still
    rebuild it."""
    session = FakeSession()
    w = Worker(FUSION, session, KEYS)
    now = time.time_ns() - 10**9
    feed(w, session, KEYS.data("T0/AB"), error_pose(now))
    feed(w, session, KEYS.data("T1/AB"), error_pose(now + 10**7))
    service, generation, channel = w._service, w._generation, session.channels[KEYS.data("T0/AB")]
    wiring = {k: FUSION.as_dict()[k] for k in ("inputs", "relations", "parameters")}
    feed(w, session, KEYS.control("fuse"), json.dumps(wiring).encode())
    assert w.counters["rewired"] == 1
    assert (w._service, w._generation) == (service, generation)
    assert session.channels[KEYS.data("T0/AB")] is channel
    feed(w, session, KEYS.data("T0/AB"), error_pose(now + 5 * 10**6))  # late: re-filtered
    published = [decode(d) for k, d in session.puts if k == KEYS.data("fuse/fused")]
    assert [p.timestamp_ns for p in published] == [now, now + 10**7]  # nothing out of order
    assert w.counters["late"] == 1
    feed(w, session, KEYS.control("fuse"), json.dumps({"parameters": {"gate": 20.0}}).encode())
    assert w.counters["rewired"] == 2 and w._service is not service
    w.stop()


def _query_at(publisher, t: int) -> list[bytes]:
    """What ``publisher`` (a ``LatestValuePublisher``) replies to a query for time ``t``."""
    replies: list[bytes] = []
    query = SimpleNamespace(
        parameters={"t": str(t)},
        reply=lambda key, payload, encoding, attachment=None: replies.append(payload),
        reply_err=lambda payload: replies.append(b"error " + payload),
    )
    publisher._reply(query)
    return replies


def test_a_query_for_a_time_while_the_worker_is_busy_is_answered_with_a_time_out():
    """A query waits for the worker's lock at most ``ANSWER_TIMEOUT_S`` (an input's thread
    holds it through a long computation), then is answered with a time-out, never left
    hanging; the next query, once the worker is free, is answered."""
    session = FakeSession()
    w = Worker(FUSION, session, KEYS)
    now = time.time_ns() - 10**9
    feed(w, session, KEYS.data("T0/AB"), error_pose(now))
    publisher = w._publishers[KEYS.data("fuse/fused")]
    with w._lock:  # what an input's thread does while it computes
        (reply,) = _query_at(publisher, now)
    assert reply.startswith(b"error ") and b"timeout" in reply.lower()
    (reply,) = _query_at(publisher, now)
    assert decode(reply).timestamp_ns == now
    assert (w.counters["time_queries"], w.counters["internal_errors"]) == (1, 0)
    w.stop()


def test_an_unexpected_fault_answering_a_time_is_counted_and_answered(monkeypatch):
    """A bug in the answer's computation is logged and counted (``internal_errors``) and the
    querier gets a typed error at once; the worker's lock is released."""
    session = FakeSession()
    w = Worker(FUSION, session, KEYS)
    now = time.time_ns() - 10**9
    feed(w, session, KEYS.data("T0/AB"), error_pose(now))
    monkeypatch.setattr(w, "_value_at", lambda port, t: 1 / 0)
    (reply,) = _query_at(w._publishers[KEYS.data("fuse/fused")], now)
    assert reply.startswith(b"error ") and w.counters["internal_errors"] == 1
    assert w._lock.acquire(blocking=False)
    w._lock.release()
    w.stop()


def test_instants_with_too_few_correspondences_are_summarised_not_warned_each(caplog):
    """Issue 14: a hidden feature made a warning per frame; now one summary per SUMMARY_S."""
    w = Worker(SPEC, FakeSession(), KEYS)
    w._counts["too_few_correspondences"] += 5
    with caplog.at_level(logging.WARNING, logger="ubitrack.worker"):
        w._summarise(w._summary_due - 1.0)  # not due yet
        w._summarise(w._summary_due)
        w._summarise(w._summary_due)  # nothing new
    (record,) = caplog.records
    assert "5 instant(s) with too few correspondences in the last 10 s" in record.getMessage()
