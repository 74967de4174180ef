"""A real worker process with real zenoh: compute, reject bad input, rewire, stop on SIGTERM."""

from __future__ import annotations

import json
import math
import queue
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tests.integration.zenoh_helpers import (
    Collector,
    free_port,
    hub_session,
    member_flags,
    wait_until,
)
from ubitrack_agent.core import ErrorPose, Pose, Position2D, Position3D, decode, encode, se3
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.spec import ComponentSpec, InputBinding

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
            InputBinding("AB", keys.data("ART/WT"), static=True),
            InputBinding("BC", keys.data("ART/HT"), trigger=True),
        ),
        outputs={"AC": keys.data("concat1/AC")},
    )
    with hub_session(port) as session:
        tokens = []
        liveliness = session.liveliness().declare_subscriber(
            keys.worker_tokens("concat1"), lambda s: tokens.append(str(s.kind))
        )
        output = Collector(session, keys.data("concat1/AC"))
        worker = start_worker(processes, spec, port, domain, session, keys)
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
            {"port": "AB", "key": keys.data("ART/WT"), "static": True},
            {"port": "BC", "key": keys.data("ART/HT2"), "trigger": True},
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
        wait_until(
            lambda: query_status(session, keys, "concat1")["counters"]["rejected_commands"] == 2
        )

        # 5. SIGTERM: clean exit, token gone
        worker.send_signal(signal.SIGTERM)
        assert worker.wait(timeout=10) == 0
        wait_until(lambda: "SampleKind.DELETE" in tokens)
        liveliness.undeclare()


def settled(session, keys: KeySpace, instance: str, **expected: int) -> dict | None:
    """The worker's counters once they show ``expected`` (the output can overtake them)."""
    counters = query_status(session, keys, instance)["counters"]
    return counters if all(counters[k] == v for k, v in expected.items()) else None


def query_status(session, keys: KeySpace, instance: str) -> dict:
    replies = list(session.get(keys.status(instance), timeout=5.0))
    assert replies and replies[0].ok is not None
    return json.loads(replies[0].ok.payload.to_bytes())


def start_worker(processes, spec: ComponentSpec, port: int, domain: str, session, keys):
    tokens = []
    watcher = session.liveliness().declare_subscriber(
        keys.worker_tokens(spec.instance), lambda s: tokens.append(str(s.kind)), history=True
    )
    worker = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "ubitrack_agent.services.worker",
            "--spec",
            spec.to_json(),
            *member_flags(port, domain),
        ],
        start_new_session=True,
    )
    processes.append(worker)
    wait_until(lambda: "SampleKind.PUT" in tokens)
    watcher.undeclare()
    return worker


def test_time_expanded_tracker_alignment_and_space_expanded_fusion(processes):
    """3D-3D pose estimation accumulating one point over time; fusion over parallel edges."""
    port = free_port()
    domain = f"x{port}"
    keys = KeySpace(f"ubitrack/{domain}")
    alignment = ComponentSpec(
        instance="align",
        service="pose_estimation_3d3d",
        inputs=(
            InputBinding("AF", keys.data("A/F"), trigger=True),
            InputBinding("BF", keys.data("B/F")),
        ),
        outputs={"AB": keys.data("align/AB")},
        expansion="time",
        time_expansion={"min_motion": 0.01},
    )
    fusion = ComponentSpec(
        instance="fuse",
        service="fusion",
        inputs=tuple(InputBinding("AB", keys.data(f"T{i}/AB"), trigger=i == 0) for i in range(2)),
        outputs={"fused": keys.data("fuse/fused")},
        expansion="space",
        parameters={"policy": "synchronised"},
    )
    q, t = Rotation.random(rng=RNG).as_quat(), RNG.normal(size=3)
    with hub_session(port) as session:
        aligned = Collector(session, keys.data("align/AB"))
        fused = Collector(session, keys.data("fuse/fused"))
        start_worker(processes, alignment, port, domain, session, keys)
        start_worker(processes, fusion, port, domain, session, keys)
        a_pub, b_pub = (session.declare_publisher(keys.data(e)) for e in ("A/F", "B/F"))
        trackers = [session.declare_publisher(keys.data(f"T{i}/AB")) for i in range(2)]
        wait_until(lambda: all(p.matching_status.matching for p in (a_pub, b_pub, *trackers)))
        points = RNG.uniform(-0.5, 0.5, (5, 3))
        for i, p in enumerate(points):
            stamp = 10_000 + i * 1_000_000
            b_pub.put(encode(Position3D(stamp, p)))
            time.sleep(0.02)  # B's sample is in the worker's buffer before A triggers
            a_pub.put(encode(Position3D(stamp, se3.transform_points(q, t, p))))
        results = [decode(aligned.next(), expected=(Pose, ErrorPose)) for _ in range(3)]
        np.testing.assert_allclose(
            se3.to_matrix(results[-1].rotation, results[-1].translation),
            se3.to_matrix(q, t),
            atol=1e-9,
        )
        stamp = 50_000_000
        trackers[1].put(encode(ErrorPose(stamp, q, [1.0, 0, 0], np.eye(6) * 1e-6)))
        time.sleep(0.02)
        trackers[0].put(encode(ErrorPose(stamp, q, [1.2, 0, 0], np.eye(6) * 1e-6)))
        result = decode(fused.next(), expected=ErrorPose)
        np.testing.assert_allclose(result.translation, [1.1, 0, 0], atol=1e-9)
        np.testing.assert_allclose(np.diag(result.covariance), 0.5e-6, rtol=1e-6)


def test_asynchronous_fusion_publishes_each_estimate_and_answers_times(processes):
    """The default fusion: every estimate is published at once (none waits for the other
    tracker), a late one is re-filtered, a flipped one is gated; queries at a time are answered
    by the filter (20 ms ahead on a constant-velocity motion) and, through a concatenation
    downstream, by the concatenation asking the filter in turn."""
    from ubitrack_agent.core.errors import ExtrapolationError
    from ubitrack_agent.net.time_queries import fetch_at

    port = free_port()
    domain = f"f{port}"
    keys = KeySpace(f"ubitrack/{domain}")
    fusion = ComponentSpec(
        instance="fuse",
        service="fusion",
        inputs=tuple(InputBinding("AB", keys.data(f"T{i}/AB"), trigger=True) for i in range(2)),
        outputs={"fused": keys.data("fuse/fused")},
        expansion="space",
    )
    concat = ComponentSpec(
        instance="concat",
        service="concatenation",
        inputs=(
            InputBinding("AB", keys.data("fuse/fused"), trigger=True),
            InputBinding("BC", keys.data("S/BC"), static=True),
        ),
        outputs={"AC": keys.data("concat/AC")},
    )
    q = Rotation.random(rng=RNG).as_quat()
    velocity = np.array([0.3, -0.1, 0.05])
    covariance = np.diag([1e-6] * 3 + [1e-8] * 3)
    start = time.time_ns() - 10**9

    def truth(t_ns: int) -> np.ndarray:
        return velocity * (t_ns - start) * 1e-9

    def estimate(t_ns: int) -> ErrorPose:
        return ErrorPose(t_ns, q, truth(t_ns), covariance)

    static = Pose(0, [0, 0, 0, 1.0], [0, 0, 1.0])
    with hub_session(port) as session:
        fused = Collector(session, keys.data("fuse/fused"))
        static_publisher = session.declare_publisher(keys.data("S/BC"))
        start_worker(processes, fusion, port, domain, session, keys)
        start_worker(processes, concat, port, domain, session, keys)
        trackers = [session.declare_publisher(keys.data(f"T{i}/AB")) for i in range(2)]
        wait_until(lambda: all(p.matching_status.matching for p in (*trackers, static_publisher)))
        static_publisher.put(encode(static))
        times = [start + k * 10**7 for k in range(40)]  # 100 Hz, alternating trackers

        def first_output() -> bool:  # until the worker's publisher has found the collector
            trackers[0].put(encode(estimate(times[0])))
            time.sleep(0.1)
            return not fused.items.empty()

        wait_until(first_output, timeout=30.0)
        time.sleep(0.2)
        fused.drain()
        late = times[20]
        outputs = []
        for k, t_ns in enumerate(times[1:], start=1):
            if t_ns == late:
                continue
            trackers[k % 2].put(encode(estimate(t_ns)))
            # Each estimate's output before the next is sent: the two trackers' keys reach the
            # worker on threads of their own, which a loaded machine may run in either order
            # (a generous deadline: other jobs may load this machine).
            outputs.append(decode(fused.next(timeout=30.0), expected=ErrorPose))
            if t_ns == times[21]:
                trackers[0].put(encode(estimate(late)))  # arrives after a newer one
        flipped = Rotation.from_quat(q) * Rotation.from_rotvec([0, 0, np.pi])
        newest = times[-1] + 5 * 10**6
        trackers[1].put(encode(ErrorPose(newest, flipped.as_quat(), truth(newest), covariance)))
        assert [o.timestamp_ns for o in outputs] == [t for t in times[1:] if t != late]
        assert np.linalg.norm(outputs[-1].translation - truth(times[-1])) < 1e-4
        assert wait_until(lambda: settled(session, keys, "fuse", late=1, gated=1))
        with pytest.raises(queue.Empty):
            fused.next(timeout=0.3)  # the flip published nothing

        ahead = times[-1] + 20 * 10**6
        value = decode(fetch_at(session, keys.data("fuse/fused"), ahead, 1.0), expected=ErrorPose)
        assert value.timestamp_ns == ahead
        assert np.linalg.norm(value.translation - truth(ahead)) < 1e-4
        composed = decode(fetch_at(session, keys.data("concat/AC"), ahead, 1.0))
        lever = se3.transform_points(q, truth(ahead), np.array([[0, 0, 1.0]]))[0]
        assert composed.timestamp_ns == ahead
        assert np.linalg.norm(composed.translation - lever) < 1e-4
        too_far = times[-1] + 500 * 10**6  # beyond the filter's prediction bound
        for key in (keys.data("fuse/fused"), keys.data("concat/AC")):
            with pytest.raises(ExtrapolationError, match="ahead"):
                fetch_at(session, key, too_far, 1.0)
