"""Live fuzzing of the workers' and the host manager's network entry points (issue 11).

Real processes on loopback: a concatenation worker, a host manager with a warm pool, a relay it
started from the pool and an idle pool member. Hypothesis drives every entry point with hostile
input (measurements on the workers' data keys, control commands, pool specifications, host
requests), a bounded number of examples; then every process must be alive, still compute the
right outputs for known inputs, and its counters must show the rejections.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.integration.fuzz_inputs import (
    control_commands,
    host_requests,
    measurement_payloads,
    nested_json,
    pool_specifications,
)
from tests.integration.test_host import Network, network, relay
from tests.integration.test_worker import expected, query_status, random_pose, start_worker
from tests.integration.zenoh_helpers import Collector, wait_until
from ubitrack_agent.core import Pose, decode, encode, se3
from ubitrack_agent.net.host_protocol import Start, encode_request
from ubitrack_agent.net.spec import ComponentSpec, InputBinding

pytestmark = pytest.mark.integration

IDENTITY = ([0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0])

EXAMPLES = 400
"""Hostile messages in all (the test takes about 20 s on two shared CPUs, start-up included)."""


@pytest.fixture
def hub(processes) -> Iterator[Network]:
    yield from network(processes, as_hub=True)


def test_hostile_input_never_stops_a_worker_or_the_host_manager(hub):
    keys = hub.keys
    concat = ComponentSpec(
        instance="fz1",
        service="concatenation",
        inputs=(
            InputBinding("AB", keys.data("F/WT"), static=True),
            InputBinding("BC", keys.data("F/HT"), trigger=True),
        ),
        outputs={"AC": keys.data("fz1/AC")},
    )
    pools: dict[str, str] = {}
    pool_watch = hub.session.liveliness().declare_subscriber(
        keys.all_pools(),
        lambda s: pools.__setitem__(keys.parse_pool(str(s.key_expr)), str(s.kind)),
        history=True,
    )
    host = hub.host("fz", pool_size=1)
    worker = start_worker(hub.processes, concat, hub.port, hub.domain, hub.session, keys)
    wait_until(lambda: hub.status("fz")["pool_ready"] == 1, timeout=40)
    ok, started = hub.ask("fz", encode_request(Start(relay(keys, "rl1"))))
    assert ok, started
    wait_until(lambda: query_status_or_none(hub, "rl1"), timeout=20)
    # The pool refills after a quiet while: that member is the one fuzzed, and runs rl2 later.
    wait_until(lambda: hub.status("fz")["pool_ready"] == 1, timeout=40)
    idle = [pool_id for pool_id, kind in pools.items() if kind == "SampleKind.PUT"]
    assert len(idle) == 1, pools

    entry_points = {
        "measurement": (st.sampled_from(["F/WT", "F/HT", "src/in"]), measurement_payloads),
        "control": (st.sampled_from(["fz1", "rl1"]), control_commands()),
        "pool": (st.just(idle[0]), pool_specifications(relay(keys, "rl9"))),
        "host": (st.just("fz"), host_requests(relay(keys, "rl9"))),
    }
    sent: dict[str, int] = dict.fromkeys(entry_points, 0)

    @settings(
        deadline=None,
        max_examples=EXAMPLES,
        database=None,
        suppress_health_check=list(HealthCheck),
    )
    @given(st.sampled_from(sorted(entry_points)), st.data())
    def drive(kind: str, data: st.DataObject) -> None:
        targets, payloads = entry_points[kind]
        target, payload = data.draw(targets), data.draw(payloads)
        sent[kind] += 1
        if kind == "measurement":
            hub.session.put(keys.data(target), payload)
        elif kind == "control":
            hub.session.put(keys.control(target), payload)
        elif kind == "pool":
            hub.session.put(keys.pool(target), payload)
        else:
            list(hub.session.get(keys.host_request(target), payload=payload, timeout=5.0))

    drive()
    pool_watch.undeclare()
    # The regressions of issue 11, each once whatever hypothesis drew.
    six_floats = msgpack.unpackb(encode(Pose(1, [0, 0, 0, 1], [0, 0, 0])))
    six_floats["translation"] = np.zeros(6).tobytes()
    hub.session.put(keys.data("F/HT"), msgpack.packb(six_floats))
    hub.session.put(keys.data("F/HT"), encode(Pose(time.time_ns() + 86_400 * 10**9, *IDENTITY)))
    hub.session.put(keys.control("fz1"), nested_json(100_000, as_map=False))
    hub.session.put(keys.pool(idle[0]), nested_json(100_000, as_map=True))

    # Every process is alive and answers.
    assert worker.poll() is None and host.poll() is None
    assert all(sent.values()), sent
    time.sleep(0.5)  # the inboxes drain

    # The worker still computes correctly.
    output = Collector(hub.session, keys.data("fz1/AC"))
    wt = hub.session.declare_publisher(keys.data("F/WT"))
    ht = hub.session.declare_publisher(keys.data("F/HT"))
    now = time.time_ns()
    static = random_pose(now)
    wt.put(encode(static))
    time.sleep(0.1)
    output.drain()
    for i in range(1, 4):
        moving = random_pose(now + i * 1_000_000)
        ht.put(encode(moving))
        result = decode(output.next(), expected=Pose)
        assert result.timestamp_ns == moving.timestamp_ns
        np.testing.assert_allclose(
            se3.to_matrix(result.rotation, result.translation),
            expected(static, moving),
            atol=1e-12,
        )

    # The relay from the pool still relays.
    relayed = Collector(hub.session, keys.data("rl1/out"))
    source = hub.session.declare_publisher(keys.data("src/in"))
    value = Pose(time.time_ns(), [0, 0, 0, 1], [4.0, 5.0, 6.0])
    source.put(encode(value))
    assert decode(relayed.next(), expected=Pose) == value

    # The counters moved, and nothing was an internal error.
    counters = query_status(hub.session, keys, "fz1")["counters"]
    assert counters["rejected"] > 0 and counters["rejected_future"] > 0, counters
    assert counters["rejected_commands"] > 0 and counters["internal_errors"] == 0, counters
    host_counters = hub.status("fz")["counters"]
    assert host_counters.get("malformed_requests", 0) > 0, host_counters
    assert host_counters.get("internal_errors", 0) == 0, host_counters

    # The fuzzed idle pool member takes the next start and shows what it rejected.
    ok, second = hub.ask("fz", encode_request(Start(relay(keys, "rl2"))))
    assert ok, second
    status = wait_until(lambda: query_status_or_none(hub, "rl2"), timeout=20)
    assert status["pid"] == second["pid"]
    assert status["pool"]["rejected_specs"] > 0 and status["pool"]["internal_errors"] == 0
    assert worker.poll() is None and host.poll() is None


def query_status_or_none(hub: Network, instance: str) -> dict | None:
    replies = list(hub.session.get(hub.keys.status(instance), timeout=1.0))
    ok = [reply.ok for reply in replies if reply.ok is not None]
    return json.loads(ok[0].payload.to_bytes()) if ok else None
