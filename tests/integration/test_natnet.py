"""``ubitrack sim natnet`` -> NatNet UDP on loopback -> ``ubitrack natnet`` -> zenoh, as separate
processes: unicast at NatNet 3.1 (connect, model definitions by name, keep-alive) and
multicast at 4.2 (time-to-live 0 on 127.0.0.1: the frames stay on this host), with hostile
datagrams sent into the multicast stream. Every measurement is compared with the scenario's
ground truth at its own timestamp."""

from __future__ import annotations

import ast
import json
import re
import socket
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tests.integration.conftest import kill_tagged
from tests.integration.test_simulators import collect, free_udp_port, start, stop_cleanly
from tests.integration.zenoh_helpers import (
    Collector,
    free_port,
    hub_session,
    member_flags,
    wait_until,
)
from ubitrack_agent.commands.demo import natnet_flags
from ubitrack_agent.core import ErrorPose
from ubitrack_agent.io.natnet import format as natnet
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.transport import fetch_latest
from ubitrack_agent.sim_trackers.scenario import load_scenario

pytestmark = pytest.mark.integration

SCENARIO = load_scenario()
WORLD = SCENARIO.world
GROUP = "239.255.42.99"


def _counters(log: str) -> dict:
    match = re.search(r"natnet counters: (\{.*\})", log)
    assert match, log
    return ast.literal_eval(match.group(1))


def _check_against_truth(samples: list) -> float:
    """Compare with the truth at each sample's timestamp; returns how late the timestamps are
    (the median, seconds), estimated along the body's velocity. Device
    timestamps are the receive time minus NatNet's latency, so they carry the receive
    time's scheduling jitter (milliseconds on this 2-core machine under test load): the
    position noise is checked across the velocity, the timing along it."""
    across, angle_errors, offsets = [], [], []
    for sample in samples:
        assert isinstance(sample, ErrorPose)
        q, t = WORLD.pose("ART", "HT", sample.timestamp_ns)
        velocity = (
            WORLD.pose("ART", "HT", sample.timestamp_ns + 1_000_000)[1]
            - WORLD.pose("ART", "HT", sample.timestamp_ns - 1_000_000)[1]
        ) / 2e-3
        error = sample.translation - t
        offset = float(error @ velocity / (velocity @ velocity))  # -lateness
        offsets.append(-offset)
        across.append(np.linalg.norm(error - offset * velocity) * 1000)
        delta = Rotation.from_quat(sample.rotation) * Rotation.from_quat(q).inv()
        angle_errors.append(np.degrees(delta.magnitude()))
    # Noise 0.3 mm and 0.05 deg per axis (3D RMS sqrt(3) times that; two axes across).
    assert np.sqrt(np.mean(np.square(across))) < 2 * 0.3 * np.sqrt(2)
    assert np.sqrt(np.mean(np.square(angle_errors))) < 0.5
    assert len({s.timestamp_ns for s in samples}) == len(samples)
    lateness = float(np.median(offsets))
    assert -0.002 < lateness < 0.010, lateness
    return lateness


@pytest.mark.parametrize(
    ("version", "multicast"), [("3.1", False), ("4.2", True)], ids=["unicast-3.1", "multicast-4.2"]
)
def test_sim_natnet_through_the_natnet_adapter_matches_ground_truth(processes, version, multicast):
    port, command, data = free_port(), free_udp_port(), free_udp_port()
    domain = f"natnet{port}"
    keys = KeySpace(f"ubitrack/{domain}")
    transport = ["--multicast-group", GROUP] if multicast else []
    with hub_session(port) as hub:
        moving = Collector(hub, keys.measured("ART", "ART_HT"))
        flags = natnet_flags(SCENARIO.art, command, data, multicast=multicast)
        adapter = start(processes, "natnet", *flags, *member_flags(port, domain))
        wait_until(lambda: fetch_latest(hub, keys.fragment("ART"), timeout=0.2))
        fragment = json.loads(fetch_latest(hub, keys.fragment("ART"))[0])
        assert {(e["name"], e["static"]) for e in fragment["edges"]} == {
            ("ART_WT", True),
            ("ART_HT", False),
        }
        server = start(
            processes,
            "sim", "natnet", "--command-port", str(command), "--data-port", str(data),
            "--natnet-version", version, *transport,
        )  # fmt: skip
        samples = collect(moving, 60)
        _check_against_truth(samples)
        if multicast:  # hostile datagrams into the stream, then it still flows
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
                sock.setsockopt(
                    socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton("127.0.0.1")
                )
                sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
                good = natnet.build_frame(natnet.Frame(1), natnet.NatNetVersion(4, 2))
                for cut in range(5, 25):
                    sock.sendto(good[:cut], (GROUP, data))  # header size disagrees
                sock.sendto(b"\x07\x00\x04\x00\xff\xff\xff\xff", (GROUP, data))  # too short
            moving.drain()
            _check_against_truth(collect(moving, 30))
        static = wait_until(lambda: fetch_latest(hub, keys.measured("ART", "ART_WT")))
        assert static
        stop_cleanly(server)
        counters = _counters(stop_cleanly(adapter))
        assert counters["model_definitions"] >= 1 and counters["published"] >= 90
        assert counters.get("rejected", 0) == (21 if multicast else 0)
        assert not any(name.startswith("unmapped_body_") for name in counters)
        moving.subscriber.undeclare()


def test_a_bad_mapping_or_no_server_answer(processes):
    """No mapping: exit 2 with the reason. A silent server: the adapter keeps trying, says so
    in its status line, and stops cleanly."""
    out = start(processes, "natnet", "--unicast")
    _, err = out.communicate(timeout=20)
    assert out.returncode == 2 and "no rigid body mapped" in err
    port = free_port()
    silent = start(
        processes,
        "natnet", "--unicast", "--command-port", str(free_udp_port()), "--body", "HT=HT",
        "--duration", "2.5", *member_flags(port, f"silent{port}"),
    )  # fmt: skip
    with hub_session(port):
        _, err = silent.communicate(timeout=30)
    assert silent.returncode == 0, err
    counters = _counters(err)
    assert counters.get("received", 0) == 0


def test_the_demo_with_an_optitrack_in_place_of_the_art_fuses(processes):
    """``ubitrack demo --tracker natnet``: calibration, fusion of 2D-3D pose estimation with
    the NatNet path beating the camera alone, reconfiguration both ways, nothing left over."""
    port = free_port()
    domain = f"demonatnet{port}"
    demo = subprocess.Popen(
        [
            sys.executable, "-m", "ubitrack_agent.cli", "demo", "--tracker", "natnet",
            "--phase-seconds", "4", "--json", "--seed", "5",
            "--listen", f"tcp/127.0.0.1:{port}", "--domain", domain,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )  # fmt: skip
    processes.append(demo)
    out, err = demo.communicate(timeout=180)
    assert demo.returncode == 0, err[-3000:]
    lines = [json.loads(line) for line in out.splitlines() if line.startswith("{")]
    assert any("natnet" in name for name in lines[0]["processes"]), lines[0]
    (calibration,) = [line for line in lines if line["event"] == "calibration"]
    assert calibration["outcome"] == "converged"
    assert calibration["error_mm"] < 2.0 and calibration["error_deg"] < 0.2
    summaries = {line["phase"]: line for line in lines if line["event"] == "summary"}
    assert list(summaries) == ["fused", "camera only", "fused again"]
    assert all(summary["samples"] > 20 for summary in summaries.values()), summaries
    assert summaries["fused"]["error_mm_rms"] < summaries["camera only"]["error_mm_rms"]
    for phase in ("camera only", "fused again"):
        assert summaries[phase]["reconfiguration_ms"] is not None, summaries[phase]
    assert lines[-1]["event"] == "verdict" and lines[-1]["fused_better_than_camera_only"]
    assert kill_tagged(domain) == []
