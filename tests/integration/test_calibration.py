"""Live calibration end to end: a static relation computed over time converges, is saved by the
calibration store, survives kill -9 of the store, and is answered from the store afterwards.

Two noise-free trackers (``sim_trackers.exact_tracker --hide-world``) see the same moving head
target HT but announce nothing about where they stand, so ``ART -> T2`` is a static relation
only dynamic measurements reveal: ``ART->HT (T2->HT)^-1`` averaged over time. The truth used
to check the result comes from the simulator (``tracker_pose``), never from the system.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest
import yaml

from sim_trackers.exact_tracker import tracker_pose
from tests.integration.zenoh_helpers import free_port, member_flags, wait_until
from ubitrack_agent.core import quaternions, se3
from ubitrack_agent.net import config
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.session import open_session
from ubitrack_agent.net.transport import fetch_latest

pytestmark = pytest.mark.integration

ART, T2 = ("ART", 30.0, 2.0), ("T2", -40.0, -1.0)


def true_art_t2() -> tuple[np.ndarray, np.ndarray]:
    """ART->T2 = ART->WT (T2->WT)^-1 from the simulator's placement of the two trackers."""
    return se3.compose(*tracker_pose(*ART[1:]), *se3.invert(*tracker_pose(*T2[1:])))


def test_calibrate_save_survive_kill_9_and_answer_from_the_store(processes, tmp_path):
    port = free_port()
    domain = f"cal{port}"
    member = member_flags(port, domain)
    calibration_file = tmp_path / "calibration.yaml"

    def start(*command: str) -> subprocess.Popen:
        process = subprocess.Popen([sys.executable, *command], start_new_session=True)
        processes.append(process)
        return process

    def calibrate(*extra: str) -> list[dict]:
        command = ["calibrate", "ART", "T2", "--json", "--timeout", "60", *extra, *member]
        out = subprocess.run(
            [sys.executable, "-m", "ubitrack_agent.cli", *command],
            capture_output=True,
            text=True,
            timeout=90,
        )
        assert out.returncode == 0, out.stderr[-2000:] + out.stdout[-3000:]
        return [json.loads(line) for line in out.stdout.splitlines()]

    def store() -> subprocess.Popen:
        return start("-m", "ubitrack_agent.cli", "store", str(calibration_file), *member)

    agent = ["agent", "--listen", f"tcp/127.0.0.1:{port}", "--domain", domain]
    running_agent = start("-m", "ubitrack_agent.cli", *agent)
    for provider, (frame, yaw, x) in (("art", ART), ("t2", T2)):
        tracker = ["--provider", provider, "--tracker", frame, "--yaw", str(yaw), "--x", str(x)]
        start("-m", "sim_trackers.exact_tracker", *tracker, "--hide-world", *member)
    saving = store()

    lines = calibrate("--save")
    events = [line["event"] for line in lines]
    assert events[-2:] == ["converged", "saved"], events
    assert "progress" in events  # the person calibrating saw it go
    converged = lines[-2]["value"]
    q_true, t_true = true_art_t2()
    error_mm = np.linalg.norm(np.array(converged["translation"]) - t_true) * 1000
    relative = quaternions.multiply(quaternions.conjugate(q_true), converged["rotation"])
    assert error_mm < 1.0 and np.degrees(quaternions.angle(relative)) < 0.1
    assert lines[-1]["file"] == str(calibration_file.resolve())

    # Durable: the file holds the value and where it came from, whatever happens to the store,
    # the agent and its workers (the agent's process group holds its host manager and workers).
    saving.send_signal(signal.SIGKILL)
    saving.wait()
    os.killpg(running_agent.pid, signal.SIGKILL)
    running_agent.wait()
    (entry,) = yaml.safe_load(calibration_file.read_text())["edges"]
    assert (entry["from"], entry["to"], entry["type"]) == ("ART", "T2", "6D")
    np.testing.assert_allclose(entry["translation"], converged["translation"])
    assert entry["provenance"]["samples"] >= 50
    assert not [name for name in os.listdir(tmp_path) if name.endswith(".tmp")]

    # Restarted, the store serves it: once the agent has it in the SRG, the static query is
    # answered from the store without calibrating again.
    start("-m", "ubitrack_agent.cli", *agent)
    store()
    hub = config.Settings(listen=(f"tcp/127.0.0.1:{port}",), domain=domain)
    with open_session(config.member_of(hub)) as session:
        keys = KeySpace(hub.key_prefix)

        def stored_edge_planned() -> bool:
            replies = fetch_latest(session, keys.agent_status(), timeout=0.5)
            return bool(replies) and "store.ART_T2" in json.loads(replies[0]).get("providers", {})

        wait_until(stored_edge_planned, timeout=20)
    (known,) = calibrate()
    assert known["event"] == "known"
    np.testing.assert_allclose(known["value"]["translation"], converged["translation"])


def test_a_static_query_on_a_moving_relation_is_answered_not_static(processes):
    """ART->HT moves (the head target walks its path): asked as static, the averaging flow
    finds the samples moving more than their noise explains, and says so."""
    port = free_port()
    domain = f"cal{port}"
    member = member_flags(port, domain)
    agent = ["agent", "--listen", f"tcp/127.0.0.1:{port}", "--domain", domain]
    for command in (
        ["-m", "ubitrack_agent.cli", *agent],
        ["-m", "sim_trackers.exact_tracker", "--provider", "art", "--tracker", "ART", *member],
    ):
        processes.append(subprocess.Popen([sys.executable, *command], start_new_session=True))
    command = ["calibrate", "ART", "HT", "--json", "--timeout", "60", *member]
    out = subprocess.run(
        [sys.executable, "-m", "ubitrack_agent.cli", *command],
        capture_output=True,
        text=True,
        timeout=90,
    )
    assert out.returncode == 1, out.stderr[-2000:]
    last = json.loads(out.stdout.splitlines()[-1])
    assert last["event"] == "not_static" and last["motion"]["translation"] > 0.005
    assert "ART->HT:6D static is not static" in last["message"]
