"""Live calibration end to end: a static relation computed over time converges, is saved by the
calibration store, survives kill -9 of the store, and is answered from the store afterwards
(the setup: ``tests/integration/calibration_helpers.py``).
"""

from __future__ import annotations

import json
import os
import signal

import numpy as np
import pytest
import yaml

from tests.integration.calibration_helpers import ART, LiveCalibration, pose_error, true_art_t2

pytestmark = pytest.mark.integration


def test_calibrate_save_survive_kill_9_and_answer_from_the_store(processes, tmp_path):
    live = LiveCalibration(processes)
    calibration_file = tmp_path / "calibration.yaml"
    running_agent = live.agent()
    live.hidden_trackers()
    saving = live.store(calibration_file)

    lines = live.calibrate("--save")
    events = [line["event"] for line in lines]
    assert events[-2:] == ["converged", "saved"], events
    assert "progress" in events  # the person calibrating saw it go
    converged = lines[-2]["value"]
    error_mm, error_deg = pose_error(converged, true_art_t2())
    assert error_mm < 1.0 and error_deg < 0.1
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
    live.agent()
    live.store(calibration_file)
    with live.session() as session:
        live.wait_for_provider(session, "store.ART_T2")
    (known,) = live.calibrate()
    assert known["event"] == "known"
    np.testing.assert_allclose(known["value"]["translation"], converged["translation"])


def test_a_static_query_on_a_moving_relation_is_answered_not_static(processes):
    """ART->HT moves (the head target walks its path): asked as static, the averaging flow
    finds the samples moving more than their noise explains, and says so."""
    live = LiveCalibration(processes)
    live.agent()
    live.tracker("art", ART)
    out = live.run_calibrate("ART", "HT")
    assert out.returncode == 1, out.stderr[-2000:]
    last = json.loads(out.stdout.splitlines()[-1])
    assert last["event"] == "not_static" and last["motion"]["translation"] > 0.005
    assert "ART->HT:6D static is not static" in last["message"]
