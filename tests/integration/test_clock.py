"""Clocks across hosts with real zenoh on loopback and real processes: a host manager whose
clock reads 300 ms ahead measures its offset to the agent's clock as about -300 ms (within the
estimate's own uncertainty), and a worker fusing a tracker on that clock with one on the
agent's lines them up once the input carries the offset."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import numpy as np
import pytest

from tests.integration.test_host import Network, network
from tests.integration.test_worker import query_status, start_worker
from tests.integration.zenoh_helpers import (
    Collector,
    free_port,
    hub_session,
    member_flags,
    wait_until,
)
from ubitrack_agent.core import ErrorPose, decode, se3
from ubitrack_agent.io.application import Relation
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.spec import ComponentSpec, InputBinding
from ubitrack_agent.sim_trackers.exact_tracker import tracker_pose, true_wt_ht

pytestmark = pytest.mark.integration

AHEAD_MS = 300
MS = 10**6


@pytest.fixture
def net(processes):
    yield from network(processes, as_hub=False)


def clock_of(net: Network, host: str) -> dict | None:
    return net.status(host)["clock"]


def test_a_host_manager_300_ms_ahead_measures_its_offset_to_the_agent(net: Network):
    agent_host, offset_host = f"agent{net.port}", f"ahead{net.port}"
    net.agent("--pool-size", "0", "--host-name", agent_host)  # the hub: first
    net.host(
        offset_host, 0, "-m", "ubitrack_agent.services.host", "--clock-offset-ms", str(AHEAD_MS)
    )
    ahead = wait_until(lambda: clock_of(net, offset_host), timeout=30)
    assert abs(ahead["offset_ns"] + AHEAD_MS * MS) <= ahead["uncertainty_ns"]
    assert ahead["rtt_ns"] >= 0 and ahead["samples"] >= 1 and ahead["age_s"] >= 0
    wait_until(lambda: net.ask(agent_host, '{"op": "status"}')[0], timeout=30)
    same = wait_until(lambda: clock_of(net, agent_host), timeout=30)  # the agent's own host
    assert abs(same["offset_ns"]) <= same["uncertainty_ns"]
    replies = list(net.session.get(net.keys.agent_clock(), timeout=2.0))
    assert len(replies) == 1 and replies[0].ok is not None  # the active agent alone answers


def _tracker(processes, port: int, domain: str, provider: str, *extra: str) -> None:
    processes.append(
        subprocess.Popen(
            [
                sys.executable,
                *("-m", "ubitrack_agent.sim_trackers.exact_tracker", "--provider", provider),
                *("--tracker", "ART", "--yaw", "30", "--x", "2", "--hide-world"),
                *extra,
                *member_flags(port, domain),
            ],
            start_new_session=True,
        )
    )


def _errors_m(fused: Collector, count: int, after_ns: int) -> list[float]:
    """The distance of the next ``count`` fused poses stamped after ``after_ns`` from the true
    ART->HT at their timestamps (the agent's clock, real time here)."""
    q_wt, t_wt = tracker_pose(30.0, 2.0)
    errors: list[float] = []
    while len(errors) < count:
        pose = decode(fused.next(timeout=30.0), expected=ErrorPose)
        if pose.timestamp_ns > after_ns:
            _, t_true = se3.compose(q_wt, t_wt, *true_wt_ht(pose.timestamp_ns))
            errors.append(float(np.linalg.norm(pose.translation - t_true)))
    return errors


def test_a_fusion_reading_a_clock_300_ms_ahead_lines_up_with_its_offset(processes):
    port = free_port()
    domain = f"clk{port}"
    keys = KeySpace(f"ubitrack/{domain}")
    on_time, ahead = keys.measured("onTime", "HT"), keys.measured("ahead", "HT")

    def fusion(offset_ns: int) -> ComponentSpec:
        return ComponentSpec(
            instance="fuse",
            service="fusion",
            inputs=(
                InputBinding("AB", on_time, trigger=True),
                InputBinding("AB", ahead, clock_offset_ns=offset_ns),
            ),
            outputs={"fused": keys.data("fuse/fused")},
            expansion="space",
            parameters={"policy": "synchronised"},
        )

    with hub_session(port) as session:
        fused = Collector(session, keys.data("fuse/fused"))
        start_worker(processes, fusion(-AHEAD_MS * MS), port, domain, session, keys)
        _tracker(processes, port, domain, "onTime")
        _tracker(processes, port, domain, "ahead", "--clock-offset-ms", str(AHEAD_MS))
        fused.next(timeout=30.0)
        corrected = _errors_m(fused, 50, time.time_ns())
        # Noise-free trackers at 100 Hz: interpolation leaves micrometres.
        assert max(corrected) < 1e-3, corrected

        inputs = [binding.as_dict() for binding in fusion(0).inputs]
        session.put(keys.control("fuse"), json.dumps({"inputs": inputs}))
        wait_until(lambda: query_status(session, keys, "fuse")["counters"]["rewired"] == 1)
        uncorrected = _errors_m(fused, 50, time.time_ns() + 500 * MS)
        # The same flow pairing poses 300 ms apart: centimetres off (the head moves at
        # 0.15 to 0.45 m/s, and fusion weighs both trackers alike).
        assert np.median(uncorrected) > 1e-2, uncorrected


def test_the_agent_aligns_the_clocks_of_a_fusion_across_hosts(net: Network):
    """Two trackers of ART->HT, one on a host whose clock reads 300 ms ahead (its host
    manager measures that), fused by the agent's plan: the agent sets the offset on that input
    from the estimate, and the fused relation matches the truth."""
    agent_host, ahead_host = f"agent{net.port}", f"ahead{net.port}"
    net.agent("--pool-size", "1", "--host-name", agent_host)
    net.host(
        ahead_host, 1, "-m", "ubitrack_agent.services.host", "--clock-offset-ms", str(AHEAD_MS)
    )
    wait_until(lambda: clock_of(net, ahead_host), timeout=30)
    tracker = ("--tracker", "ART", "--yaw", "30", "--x", "2", "--hide-world")
    net.start(
        "-m",
        "ubitrack_agent.sim_trackers.exact_tracker",
        "--provider",
        "onTime",
        *tracker,
        host_name=agent_host,
    )
    net.start(
        "-m",
        "ubitrack_agent.sim_trackers.exact_tracker",
        "--provider",
        "ahead",
        *tracker,
        "--clock-offset-ms",
        str(AHEAD_MS),
        host_name=ahead_host,
    )
    relation = RelationId("ART", "HT", "6D")
    fused = Collector(net.session, net.keys.relation(relation))
    with Relation(net.session, net.keys, relation, application="app", host=agent_host):

        def corrected() -> dict | None:
            status = net.agent_status() or {}
            for component in status.get("components", {}).values():
                offsets = {
                    b["key"].split("/")[-2]: b.get("clock_offset_ns", 0)
                    for b in component["inputs"]
                }
                if component["service"] == "fusion" and component["alive"] and offsets.get("ahead"):
                    return {"offsets": offsets, "problems": status["clock_problems"]}
            return None

        # On a loaded machine the first clock estimates may be too uncertain for the fusion's
        # tolerance (a clock problem, reported) until more round trips narrow them.
        seen = wait_until(lambda: (s := corrected()) and not s["problems"] and s, timeout=60)
        estimate = clock_of(net, ahead_host)
        assert seen["offsets"]["onTime"] == 0
        assert abs(seen["offsets"]["ahead"] + AHEAD_MS * MS) <= 2 * estimate["uncertainty_ns"]
        errors = _errors_m(fused, 100, time.time_ns() + 500 * MS)
        # Both trackers noise-free and aligned: the filter's error stays far below the
        # centimetres a 300 ms misalignment makes (the previous test).
        assert np.median(errors) < 2e-3, errors
