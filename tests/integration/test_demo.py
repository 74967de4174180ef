"""The README's run command end to end: real zenoh on loopback and a real tracker process."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from .conftest import free_port

pytestmark = pytest.mark.integration


def test_demo_derives_the_relation_with_honest_error(processes):
    port = free_port()
    demo = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "ubitrack_agent.cli",
            "demo",
            "--duration",
            "3",
            "--json",
            "--listen",
            f"tcp/127.0.0.1:{port}",
            "--domain",
            f"test{port}",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    processes.append(demo)
    out, err = demo.communicate(timeout=60)
    assert demo.returncode == 0, err
    lines = [json.loads(line) for line in out.splitlines()]
    summary = lines[-1]
    assert summary["event"] == "summary"
    assert summary["samples"] > 30  # the tracker runs at 60 Hz once its process is up
    assert summary["rejected"] == 0
    # Noise is 0.1 deg / 0.5 mm per axis; the derived error must be of the predicted size.
    assert 0.5 * summary["predicted_error_mm_rms"] < summary["error_mm_rms"]
    assert summary["error_mm_rms"] < 2.0 * summary["predicted_error_mm_rms"]
    reports = [line for line in lines if line["event"] == "report" and line["samples"]]
    assert reports and all(len(r["translation_m"]) == 3 for r in reports)
    # The tracker child is gone: nothing of this run is left.
    leftover = subprocess.run(
        ["pgrep", "-f", f"sim_trackers.pose_publisher.*test{port}"], capture_output=True
    )
    assert leftover.returncode == 1, leftover.stdout


def test_demo_reports_a_busy_port(processes):
    import socket

    with socket.socket() as blocker:
        blocker.bind(("127.0.0.1", 0))
        blocker.listen()
        port = blocker.getsockname()[1]
        result = subprocess.run(
            [
                sys.executable,
                "-m",
                "ubitrack_agent.cli",
                "demo",
                "--duration",
                "1",
                "--listen",
                f"tcp/127.0.0.1:{port}",
            ],
            capture_output=True,
            text=True,
            timeout=30,
        )
    assert result.returncode == 2
    assert "cannot open zenoh" in result.stderr
