"""A real worker process with real zenoh: compute, reject bad input, rewire, stop on SIGTERM."""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from services.spec import ComponentSpec, InputBinding
from ubitrack_agent.core import ErrorPose, Pose, Position2D, decode, encode, se3
from ubitrack_agent.keys import KeySpace

from .conftest import free_port
from .zenoh_helpers import Collector, hub_session, member_flags, wait_until

pytestmark = pytest.mark.integration

RNG = np.random.default_rng(3)


def random_pose(t_ns: int, cov: bool = False) -> Pose:
    q, t = Rotation.random(rng=RNG).as_quat(), RNG.normal(size=3)
    if cov:
        return ErrorPose(t_ns, q, t, np.eye(6) * 1e-6)
    return Pose(t_ns, q, t)


def expected(first: Pose, second: Pose) -> np.ndarray:
    return se3.to_matrix(
        *se3.compose(first.rotation, first.translation, second.rotation, second.translation)
    )


def test_concatenation_worker_computes_rejects_rewires_and_stops(processes):
    port = free_port()
    domain = f"w{port}"
    keys = KeySpace(f"ubitrack/{domain}")
    spec = ComponentSpec(
        instance="concat1",
        service="concatenation",
        inputs=(
            InputBinding("first", keys.data("ART/WT"), static=True),
            InputBinding("second", keys.data("ART/HT"), trigger=True),
        ),
        outputs={"out": keys.data("concat1/out")},
    )
    with hub_session(port) as session:
        tokens = []
        liveliness = session.liveliness().declare_subscriber(
            f"ubitrack/{domain}/worker/**",
            lambda s: tokens.append((str(s.kind), str(s.key_expr))),
            history=True,
        )
        output = Collector(session, keys.data("concat1/out"))
        worker = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "services.worker",
                "--spec",
                spec.to_json(),
                *member_flags(port, domain),
            ],
            start_new_session=True,
        )
        processes.append(worker)
        wait_until(lambda: any("PUT" in kind for kind, _ in tokens))
        wt = session.declare_publisher(keys.data("ART/WT"))
        ht = session.declare_publisher(keys.data("ART/HT"))
        wait_until(lambda: wt.matching_status.matching and ht.matching_status.matching)

        # 1. correct output for correct input
        static = random_pose(1_000)
        wt.put(encode(static))
        time.sleep(0.05)
        for i in range(5):
            moving = random_pose(2_000 + i, cov=True)
            ht.put(encode(moving))
            result = decode(output.next(), expected=ErrorPose)
            assert result.timestamp_ns == moving.timestamp_ns
            np.testing.assert_allclose(
                se3.to_matrix(result.rotation, result.translation),
                expected(static, moving),
                atol=1e-12,
            )

        # 2. bad input is counted, the worker keeps going and stays correct
        nan_pose = encode(Pose(3_000, [0, 0, 0, 1], [0, 0, 0])).replace(
            np.zeros(3).tobytes(), np.array([0.0, math.nan, 0.0]).tobytes()
        )
        for bad in (b"garbage", encode(Position2D(3_000, [1, 2])), nan_pose, b"\x81\xa1v\x01"):
            ht.put(bad)
        moving = random_pose(4_000)
        ht.put(encode(moving))
        result = decode(output.next(), expected=Pose)
        np.testing.assert_allclose(
            se3.to_matrix(result.rotation, result.translation), expected(static, moving), atol=1e-12
        )
        counters = wait_until(lambda: settled(session, keys, "concat1", published=6))
        assert counters["rejected"] == 4

        # 3. rewire "second" to another key while running
        ht2 = session.declare_publisher(keys.data("ART/HT2"))
        rewired = [
            {"port": "first", "key": keys.data("ART/WT"), "static": True},
            {"port": "second", "key": keys.data("ART/HT2"), "trigger": True},
        ]
        session.put(keys.control("concat1"), json.dumps({"inputs": rewired}))
        wait_until(lambda: ht2.matching_status.matching)
        wait_until(lambda: not ht.matching_status.matching)
        ht.put(encode(random_pose(5_000)))  # the old input no longer counts
        moving = random_pose(6_000)
        ht2.put(encode(moving))
        result = decode(output.next(), expected=Pose)
        assert result.timestamp_ns == 6_000  # static WT history survived the rewire
        np.testing.assert_allclose(
            se3.to_matrix(result.rotation, result.translation), expected(static, moving), atol=1e-12
        )
        status = query_status(session, keys, "concat1")
        assert status["counters"]["rewired"] == 1
        assert status["spec"]["inputs"][1]["key"] == keys.data("ART/HT2")

        # 4. a malformed control command is rejected, the worker carries on
        session.put(keys.control("concat1"), b"{not json")
        session.put(keys.control("concat1"), json.dumps({"inputs": [{"port": "nope", "key": "a"}]}))
        wait_until(lambda: query_status(session, keys, "concat1")["counters"]["rejected"] == 6)

        # 5. SIGTERM: clean exit, token gone
        worker.send_signal(signal.SIGTERM)
        assert worker.wait(timeout=10) == 0
        wait_until(lambda: any("DELETE" in kind for kind, _ in tokens))
        liveliness.undeclare()


def settled(session, keys: KeySpace, instance: str, **expected: int) -> dict | None:
    """The worker's counters once they show ``expected`` (the output can overtake them)."""
    counters = query_status(session, keys, instance)["counters"]
    return counters if all(counters[k] == v for k, v in expected.items()) else None


def query_status(session, keys: KeySpace, instance: str) -> dict:
    replies = list(session.get(keys.status(instance), timeout=5.0))
    assert replies and replies[0].ok is not None
    return json.loads(replies[0].ok.payload.to_bytes())
