"""The simulators as separate processes on real zenoh (loopback) and real UDP.

(a) ``ubitrack sim art`` -> DTrack UDP -> ``ubitrack dtrack`` -> zenoh; (b) ``ubitrack sim
camera`` and ``ubitrack sim database``; (c) ``ubitrack sim world``'s ground truth. Every
measurement is compared with the scenario's ground truth at its own timestamp.
"""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys

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
from ubitrack_agent.commands.demo import dtrack_flags
from ubitrack_agent.core import ErrorPose, Pose, Position2D, Position3D, Projection, decode
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.transport import fetch_latest
from ubitrack_agent.sim_trackers.scenario import load_scenario

pytestmark = pytest.mark.integration

SCENARIO = load_scenario()
WORLD = SCENARIO.world


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def start(processes: list, *arguments: str) -> subprocess.Popen:
    process = subprocess.Popen(
        [sys.executable, "-m", "ubitrack_agent.cli", "--log-level", "INFO", *arguments],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    processes.append(process)
    return process


def stop_cleanly(process: subprocess.Popen) -> str:
    """SIGTERM, then the process must exit 0 by itself; returns its stderr."""
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=10)
    assert process.returncode == 0, err
    return err


def collect(collector: Collector, count: int) -> list:
    return [decode(collector.next(timeout=10)) for _ in range(count)]


def test_sim_art_through_the_dtrack_adapter_matches_ground_truth(processes):
    port, udp = free_port(), free_udp_port()
    domain = f"art{port}"
    keys = KeySpace(f"ubitrack/{domain}")
    with hub_session(port) as hub:
        moving = Collector(hub, keys.measured("ART", "ART_HT"))
        adapter = start(
            processes, "dtrack", *dtrack_flags(SCENARIO.art, udp), *member_flags(port, domain)
        )
        wait_until(lambda: fetch_latest(hub, keys.fragment("ART"), timeout=0.2))
        fragment = json.loads(fetch_latest(hub, keys.fragment("ART"))[0])
        assert {(e["name"], e["static"]) for e in fragment["edges"]} == {
            ("ART_WT", True),
            ("ART_HT", False),
        }
        tracker = start(processes, "sim", "art", "--port", str(udp))
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.sendto(b"fr 1\n6d 1 [0 1.000][1 2 3]\n", ("127.0.0.1", udp))  # malformed
        samples = collect(moving, 60)
        position_errors, angle_errors = [], []
        for sample in samples:
            assert isinstance(sample, ErrorPose)
            q, t = WORLD.pose("ART", "HT", sample.timestamp_ns)
            position_errors.append(np.linalg.norm(sample.translation - t) * 1000)
            delta = Rotation.from_quat(sample.rotation) * Rotation.from_quat(q).inv()
            angle_errors.append(np.degrees(delta.magnitude()))
        # Noise 0.3 mm and 0.05 deg per axis: the 3D RMS is sqrt(3) times that.
        assert np.sqrt(np.mean(np.square(position_errors))) < 2 * 0.3 * np.sqrt(3)
        assert np.sqrt(np.mean(np.square(angle_errors))) < 2 * 0.05 * np.sqrt(3)
        assert len({s.timestamp_ns for s in samples}) == len(samples)
        static = decode(wait_until(lambda: fetch_latest(hub, keys.measured("ART", "ART_WT")))[0])
        assert np.linalg.norm(static.translation - WORLD.pose("ART", "WT", 0)[1]) < 0.003
        stop_cleanly(tracker)
        log = stop_cleanly(adapter)
        assert "'rejected': 1" in log
        moving.subscriber.undeclare()


def test_sim_camera_and_database_match_the_projected_ground_truth(processes):
    port = free_port()
    domain = f"cam{port}"
    keys = KeySpace(f"ubitrack/{domain}")
    features = SCENARIO.camera.features
    with hub_session(port) as hub:
        collectors = {f: Collector(hub, keys.measured("camera", f"IP_{f}")) for f in features}
        camera = start(processes, "sim", "camera", *member_flags(port, domain))
        database = start(processes, "sim", "database", *member_flags(port, domain))
        stamps: dict[str, set[int]] = {}
        for feature, collector in collectors.items():
            samples = collect(collector, 20)
            stamps[feature] = {s.timestamp_ns for s in samples}
            errors = []
            for sample in samples:
                assert isinstance(sample, Position2D)
                truth = WORLD.project("IP", [feature], sample.timestamp_ns)[feature]
                errors.append(sample.position - truth)
                np.testing.assert_allclose(sample.covariance, np.eye(2) * 0.25)
            # Pixel noise 0.5 px per axis.
            assert 0.2 < np.std(errors) < 1.0 and np.abs(np.mean(errors)) < 0.5
        # One frame's features share its timestamp.
        assert set.intersection(*stamps.values())

        def latest(edge: str):
            return decode(wait_until(lambda: fetch_latest(hub, keys.measured("database", edge)))[0])

        projection = latest("C_IP")
        assert isinstance(projection, Projection)
        np.testing.assert_allclose(projection.matrix, WORLD.image_planes["IP"].projection_matrix())
        for feature in features:
            point = latest(f"WT_{feature}")
            assert isinstance(point, Position3D)
            np.testing.assert_allclose(point.position, WORLD.pose("WT", feature, 0)[1])
        calibration = latest("WT_A")
        assert isinstance(calibration, Pose)
        np.testing.assert_allclose(calibration.translation, WORLD.pose("WT", "A", 0)[1])
        stop_cleanly(camera)
        stop_cleanly(database)


def test_sim_world_answers_ground_truth_queries(processes):
    port = free_port()
    domain = f"world{port}"
    keys = KeySpace(f"ubitrack/{domain}")
    with hub_session(port) as hub:
        world = start(processes, "sim", "world", *member_flags(port, domain))
        t = 1_700_000_000_123_456_789

        def ask(source: str, target: str, parameters: str = f"t={t}") -> list:
            return list(hub.get(f"{keys.truth(source, target)}?{parameters}", timeout=1.0))

        replies = wait_until(lambda: ask("WT", "HT"))
        pose = decode(replies[0].ok.payload.to_bytes())
        assert pose.timestamp_ns == t
        q, translation = WORLD.pose("WT", "HT", t)
        np.testing.assert_allclose(pose.translation, translation)
        assert abs(float(pose.rotation @ q)) == pytest.approx(1.0)
        projected = decode(ask("IP", "F3")[0].ok.payload.to_bytes())
        np.testing.assert_allclose(projected.position, WORLD.project("IP", ["F3"], t)["F3"])
        assert isinstance(decode(ask("C", "IP")[0].ok.payload.to_bytes()), Projection)
        error = ask("ART", "HT", "t=yesterday")[0]
        assert error.ok is None and "integer nanoseconds" in error.err.payload.to_string()
        stop_cleanly(world)
