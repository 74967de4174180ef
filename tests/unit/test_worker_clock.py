"""An input's clock offset in the worker (``services/worker.py``) on a stand-in session: samples
from a host whose clock is 300 ms ahead line up with the others once their input carries
``clock_offset_ns``, a rewire with another offset moves what the input holds, a query for a
time goes upstream on the producer's clock, and a shift out of the timestamp range is counted."""

from __future__ import annotations

import json
import time
from types import SimpleNamespace

import numpy as np
import pytest

from tests.unit.test_worker_inputs import IDENTITY, FakeSession, error_pose, feed, pose
from ubitrack_agent.core import decode, encode
from ubitrack_agent.core.measurements import Pose
from ubitrack_agent.net.clock import Clock
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.spec import ComponentSpec, InputBinding
from ubitrack_agent.net.time_queries import requested_time
from ubitrack_agent.services.worker import Worker

KEYS = KeySpace("ubitrack/test")
MS = 10**6
AHEAD = 300 * MS
"""How far the clock of host B reads ahead of the agent's."""
SPEED = 2.0
"""m/s along x of the frame B measures."""

BASE = time.time_ns() - 10 * 10**9


def concatenation(offset_ns: int) -> ComponentSpec:
    """A->C from A->B measured on host B (its clock ``AHEAD``, the input corrected by
    ``offset_ns``) and B->C on the agent's host, both dynamic, B->C triggering."""
    return ComponentSpec(
        instance="concat1",
        service="concatenation",
        inputs=(
            InputBinding("AB", KEYS.data("B/AB"), clock_offset_ns=offset_ns),
            InputBinding("BC", KEYS.data("ref/BC"), trigger=True),
        ),
        outputs={"AC": KEYS.data("concat1/AC")},
    )


def moving(real_ns: int) -> float:
    return SPEED * (real_ns - BASE) / 1e9


def run_flow(offset_ns: int) -> tuple[Worker, list[Pose]]:
    """Host B measures A->B every 10 ms (stamped on its clock, AHEAD), the reference B->C
    (identity) 5 ms later each time; the outputs."""
    session = FakeSession()
    worker = Worker(concatenation(offset_ns), session, KEYS)
    for k in range(20):
        real = BASE + k * 10 * MS
        feed(worker, session, KEYS.data("B/AB"), pose(real + AHEAD, moving(real)))
    for k in range(10):
        feed(worker, session, KEYS.data("ref/BC"), pose(BASE + k * 10 * MS + 5 * MS, 0.0))
    published = [decode(d) for k, d in session.puts if k == KEYS.data("concat1/AC")]
    return worker, published


def test_inputs_from_a_clock_300_ms_ahead_line_up_once_corrected():
    worker, published = run_flow(-AHEAD)
    assert len(published) == 10
    for output in published:
        expected = moving(output.timestamp_ns)  # the true A->B at the trigger's time
        np.testing.assert_allclose(output.translation, [expected, 0.0, 0.0], atol=1e-9)
    worker.stop()


def test_uncorrected_they_do_not():
    """The same flow without the offset: no sample of A->B near a trigger's time, so every
    instant is dropped (the reason the correction exists)."""
    worker, published = run_flow(0)
    assert published == [] and worker.counters["dropped"] == 10
    worker.stop()


def test_asynchronous_fusion_orders_samples_on_the_agents_clock():
    """Fusion takes each sample as it comes: stamped 300 ms ahead, host B's samples would be
    the newest and the reference's all late; corrected, they interleave."""
    session = FakeSession()
    spec = ComponentSpec(
        instance="fuse",
        service="fusion",
        inputs=(
            InputBinding("AB", KEYS.data("ref/AB"), trigger=True),
            InputBinding("AB", KEYS.data("B/AB"), trigger=True, clock_offset_ns=-AHEAD),
        ),
        outputs={"fused": KEYS.data("fuse/fused")},
        expansion="space",
    )
    worker = Worker(spec, session, KEYS)
    for k in range(6):
        real = BASE + k * 5 * MS
        key, stamp = (KEYS.data("ref/AB"), real) if k % 2 else (KEYS.data("B/AB"), real + AHEAD)
        feed(worker, session, key, error_pose(stamp, moving(real)))
    published = [decode(d) for k, d in session.puts if k == KEYS.data("fuse/fused")]
    assert [p.timestamp_ns for p in published] == [BASE + k * 5 * MS for k in range(6)]
    assert worker.counters["late"] == 0
    worker.stop()


def test_a_rewire_with_another_offset_moves_what_the_input_holds():
    session = FakeSession()
    worker = Worker(concatenation(-AHEAD), session, KEYS)
    feed(worker, session, KEYS.data("B/AB"), pose(BASE + AHEAD))
    held = worker._inputs[0].buffer
    assert held.newest_time() == BASE

    def rewire(offset_ns: int) -> None:
        inputs = [binding.as_dict() for binding in concatenation(offset_ns).inputs]
        session.deliver(KEYS.control("concat1"), json.dumps({"inputs": inputs}).encode())
        worker.step(longest_s=0.0)

    rewire(-AHEAD)  # the same offset: the same buffer
    assert worker._inputs[0].buffer is held
    rewire(-AHEAD + MS)  # the estimate moved by a millisecond
    assert worker._inputs[0].buffer.newest_time() == BASE + MS
    assert worker.counters["rewired"] == 2
    worker.stop()


def test_a_sample_moved_out_of_the_timestamp_range_is_counted():
    session = FakeSession()
    worker = Worker(concatenation(-AHEAD), session, KEYS)
    feed(worker, session, KEYS.data("B/AB"), pose(AHEAD - 1))
    assert worker.counters["rejected_clock"] == 1 and len(worker._inputs[0].buffer) == 0
    worker.stop()


def test_a_sample_ahead_of_the_workers_own_clock_is_refused_on_its_sensors_clock():
    """The future bound compares the sensor's stamp with this host's clock (its settings'
    offset applied), before any correction."""
    session = FakeSession()
    ahead = Clock(-60 * 10**9)  # this host's clock reads a minute behind
    worker = Worker(concatenation(-AHEAD), session, KEYS, clock=ahead)
    feed(worker, session, KEYS.data("B/AB"), pose(time.time_ns()))
    assert worker.counters["rejected_future"] == 1
    worker.stop()


class UpstreamSession(FakeSession):
    """Answers every query for a time with the true pose at that time on the producer's clock
    (a producer that predicts), recording the times asked, by key."""

    def __init__(self) -> None:
        super().__init__()
        self.asked: dict[str, int] = {}

    def get(self, selector, timeout=None):
        key, _, parameters = selector.partition("?")
        t = requested_time(dict([parameters.split("=")]))
        self.asked[key] = t
        x = moving(t - AHEAD) if key == KEYS.data("B/AB") else 0.0  # B->C: identity
        payload = SimpleNamespace(to_bytes=lambda: encode(Pose(t, IDENTITY, [x, 0.0, 0.0])))
        return [SimpleNamespace(ok=SimpleNamespace(payload=payload, attachment=None))]


def test_a_value_at_a_time_is_asked_upstream_on_the_producers_clock():
    session = UpstreamSession()
    worker = Worker(concatenation(-AHEAD), session, KEYS)
    feed(worker, session, KEYS.data("B/AB"), pose(BASE + AHEAD, moving(BASE)))
    feed(worker, session, KEYS.data("ref/BC"), pose(BASE, 0.0))
    t = BASE + 50 * MS  # after every sample held: asked upstream
    value = worker._value_at("AC", t)
    assert session.asked == {KEYS.data("B/AB"): t + AHEAD, KEYS.data("ref/BC"): t}
    assert value.timestamp_ns == t
    assert value.translation[0] == pytest.approx(moving(t))
    worker.stop()


def test_the_spec_it_runs_shows_the_offset():
    worker = Worker(concatenation(-AHEAD), FakeSession(), KEYS)
    assert worker.status()["spec"]["inputs"][0]["clock_offset_ns"] == -AHEAD
    worker.stop()


def test_the_status_shows_each_dynamic_inputs_latency_on_the_workers_clock():
    """Samples 40 ms old when the worker takes them (B's, once corrected, on the agent's
    clock, which is this worker's here): the status's median latency per input says so."""
    session = FakeSession()
    worker = Worker(concatenation(-AHEAD), session, KEYS)
    for _ in range(5):
        now = time.time_ns()
        feed(worker, session, KEYS.data("B/AB"), pose(now - 40 * MS + AHEAD))
        feed(worker, session, KEYS.data("ref/BC"), pose(now - 40 * MS))
    latency = worker.status()["latency_ms"]
    assert set(latency) == {KEYS.data("B/AB"), KEYS.data("ref/BC")}
    for value in latency.values():
        assert 40.0 <= value < 40.0 + 10_000.0  # plus however long the feeding took (ms)
    worker.stop()
