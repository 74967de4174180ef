"""The README's run command end to end: agent, simulated A.R.T. and camera, database, and the
application, all real processes on loopback zenoh, through the three phases of the demo."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.integration.conftest import kill_tagged
from tests.integration.zenoh_helpers import free_port, hub_session

pytestmark = pytest.mark.integration


DECOYS = ("services", "sim_trackers", "templates")
"""Top-level names the repository's folders have: a user's packages of these names must not
replace the project's modules (issue [newcomer])."""


def decoy_folder(where: Path) -> Path:
    """A folder holding packages named as the repository's folders, each of which, imported,
    leaves a mark (a file named after it) and fails."""
    for name in DECOYS:
        (where / name).mkdir(parents=True)
        mark = where / f"{name}.imported"
        (where / name / "__init__.py").write_text(
            f"open({str(mark)!r}, 'w').close()\nraise ImportError('the decoy {name}')\n"
        )
    return where


def test_demo_runs_three_phases_with_sensible_errors(processes, tmp_path):
    """Run from a folder holding decoy packages, which is also on PYTHONPATH: every process
    of the system (agent, host manager, workers, simulators, application) still runs the
    project's own modules."""
    port = free_port()
    domain = f"demo{port}"
    decoys = decoy_folder(tmp_path / "work")
    path = os.pathsep.join(filter(None, (str(decoys), os.environ.get("PYTHONPATH"))))
    demo = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "ubitrack_agent.cli",
            "demo",
            "--phase-seconds",
            "4",
            "--json",
            "--listen",
            f"tcp/127.0.0.1:{port}",
            "--domain",
            domain,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        cwd=decoys,
        env={**os.environ, "PYTHONPATH": path},
    )
    processes.append(demo)
    out, err = demo.communicate(timeout=180)
    assert demo.returncode == 0, err[-3000:]
    assert sorted(p.name for p in decoys.glob("*.imported")) == []
    lines = [json.loads(line) for line in out.splitlines() if line.startswith("{")]
    (calibration,) = [line for line in lines if line["event"] == "calibration"]
    # The default database lacks C->HT: it is calibrated live before tracking on it.
    assert calibration["outcome"] == "converged" and calibration["file"]
    assert calibration["error_mm"] < 2.0 and calibration["error_deg"] < 0.2
    summaries = {line["phase"]: line for line in lines if line["event"] == "summary"}
    assert list(summaries) == ["fused", "camera only", "fused again"]
    for summary in summaries.values():
        assert summary["samples"] > 20, summary  # every phase delivered
        assert summary["error_mm_rms"] < 30.0, summary  # a few mm expected; 30 mm is gross
        # The samples judged against their own covariances: 6 if honest (one run's mean lies
        # about 4-9, its calibration's error shared by every sample); 60 is ten times over.
        assert 0.0 < summary["nees_mean"] < 60.0, summary
        # Each phase's steady state (after its first second) and worst second (issue 29).
        for unit in ("mm", "deg"):
            whole, steady, worst = (
                summary[f"{figure}_{unit}_rms"]
                for figure in ("error", "steady_error", "worst_second")
            )
            assert all(math.isfinite(v) and v > 0 for v in (whole, steady, worst)), summary
            assert worst >= steady, summary  # the worst second is no better than the rest
            assert summary[f"{unit}_within_steady"] == (whole <= 1.2 * steady), summary
    # 2D-3D pose estimation fused with the A.R.T. path beats the camera alone.
    assert summaries["fused"]["error_mm_rms"] < summaries["camera only"]["error_mm_rms"]
    for phase in ("camera only", "fused again"):
        assert summaries[phase]["reconfiguration_ms"] is not None, summaries[phase]
    verdict = lines[-1]
    assert verdict["event"] == "verdict" and verdict["every_phase_delivered"]
    assert verdict["every_phase_within_steady"] == all(
        s["mm_within_steady"] and s["deg_within_steady"] for s in summaries.values()
    )
    assert kill_tagged(domain) == []  # the demo left no process behind


def test_demo_names_the_process_that_failed(processes):
    """A broken set-up ends the demo at once with the cause, not after a silent minute: here
    another zenoh peer already holds the port the demo's agent is told to listen on."""
    port = free_port()
    domain = f"demo{port}"
    with hub_session(port):
        listen = ("--listen", f"tcp/127.0.0.1:{port}", "--domain", domain)
        demo = subprocess.Popen(
            [sys.executable, "-m", "ubitrack_agent.cli", "demo", "--phase-seconds", "1", *listen],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )
        processes.append(demo)
        _, err = demo.communicate(timeout=60)
    assert demo.returncode == 1
    assert "ubitrack demo: agent (status 2) ended before C->A flowed" in err, err[-2000:]
    assert kill_tagged(domain) == []
