"""The figure-1 set-up recorded live and replayed (issue 30, "Done when"): shared by
``tests/integration/test_recording.py`` (short) and ``bench/recording_bench.py`` (30 s).

:func:`record_live` runs the agent, the simulated calibration database, camera and A.R.T.
tracker with its DTrack adapter (as ``ubitrack demo`` starts them: ``commands.demo``), and
``ubitrack record``; it calibrates ``C -> HT`` live with ``ubitrack calibrate`` while the
recording runs, records on for the rest of ``seconds`` and stops the recorder with SIGINT.
:func:`replay_into_fresh_agent` starts a new agent on another port and domain, with no
simulator, runs ``ubitrack replay`` of the file and calibrates ``C -> HT`` on it, and collects
``C -> A`` samples as an application. Every process is real, on loopback with multicast off,
and goes into the caller's ``processes`` list (the fixture kills them, pass or fail).
"""

from __future__ import annotations

import json
import queue
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from tests.integration.calibration_helpers import LiveCalibration
from ubitrack_agent.commands.demo import _free_udp_port, dtrack_flags
from ubitrack_agent.core import quaternions
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.sim_trackers.scenario import load_scenario

PROVIDERS = ("database", "camera", "ART")
"""The figure-1 scenario's providers (its database, camera and art sections)."""


class Network(LiveCalibration):
    """One agent's loopback port and domain (``calibration_helpers``), and ``ubitrack``
    commands on it whose output a test reads."""

    def ubitrack(self, *arguments: str, **popen: Any) -> subprocess.Popen:
        """``ubitrack ARGUMENTS`` in its own process group."""
        process = subprocess.Popen(
            [sys.executable, "-m", "ubitrack_agent.cli", *arguments],
            start_new_session=True,
            stdin=subprocess.DEVNULL,
            **popen,
        )
        self.processes.append(process)
        return process

    def wait_for_providers(self) -> None:
        """Until the agent has the figure-1 providers in its SRG."""
        with self.session() as session:
            for provider in PROVIDERS:
                self.wait_for_provider(session, provider)

    def calibrate_c_ht(self) -> dict:
        """``ubitrack calibrate C HT`` to its end: the converged line, and the time it took
        (``seconds``)."""
        started = time.monotonic()
        out = self.run_calibrate("C", "HT")
        assert out.returncode == 0, out.stderr[-2000:] + out.stdout[-2000:]
        lines = [json.loads(line) for line in out.stdout.splitlines()]
        converged = [line for line in lines if line["event"] == "converged"]
        assert converged, out.stdout[-2000:]
        return {**converged[-1], "seconds": time.monotonic() - started}


def start_sensors(network: Network, seed: int) -> None:
    """The figure-1 simulators and DTrack adapter as ``ubitrack demo`` starts them."""
    scenario = load_scenario(None)
    udp = _free_udp_port()
    quiet = "--quiet"
    network.ubitrack("sim", "database", quiet, *network.member)
    network.ubitrack("sim", "camera", quiet, "--seed", str(seed + 1), *network.member)
    network.ubitrack("sim", "art", quiet, "--port", str(udp), "--seed", str(seed))
    network.ubitrack("dtrack", quiet, *dtrack_flags(scenario.art, udp), *network.member)


def stop(process: subprocess.Popen, timeout: float = 20.0) -> str:
    """SIGINT (Ctrl-C) to ``process``; its standard output once it ended."""
    process.send_signal(signal.SIGINT)
    out, _ = process.communicate(timeout=timeout)
    return out or ""


def record_live(processes: list, path: Path, seconds: float, seed: int = 7) -> dict:
    """Record the live figure-1 set-up for ``seconds`` (at least until C->HT converged live)
    to ``path``; the live calibration, the recorder's lines and its exit status."""
    live = Network(processes)
    live.agent()
    recorder = live.ubitrack(
        "record", str(path), "--json", *live.member, stdout=subprocess.PIPE, text=True
    )
    start_sensors(live, seed)
    live.wait_for_providers()
    started = time.monotonic()
    calibration = live.calibrate_c_ht()
    time.sleep(max(0.0, seconds - (time.monotonic() - started)))
    out = stop(recorder)
    recorded = time.monotonic() - started
    for process in processes:  # the live system goes: the replay must do without it
        if process.poll() is None:
            process.send_signal(signal.SIGTERM)
    for process in processes:
        process.wait(timeout=20)
    processes.clear()
    return {
        "calibration": calibration,
        "recorder": json_lines(out),
        "recorder_status": recorder.returncode,
        "seconds": recorded,
    }


def replay_into_fresh_agent(processes: list, path: Path, track_seconds: float = 3.0) -> dict:
    """Replay ``path`` into a new agent: the C->HT calibration on it, and the C->A samples an
    application received in ``track_seconds`` after it (count, rate)."""
    from ubitrack_agent.io.application import Relation
    from ubitrack_agent.net.keys import RelationId

    fresh = Network(processes)
    fresh.agent()
    replay = fresh.ubitrack(
        "replay", str(path), "--json", *fresh.member, stdout=subprocess.PIPE, text=True
    )
    samples: queue.SimpleQueue = queue.SimpleQueue()
    fresh.wait_for_providers()
    calibration = fresh.calibrate_c_ht()
    with fresh.session() as session:
        keys = KeySpace(fresh.hub.key_prefix)
        with Relation(session, keys, RelationId("C", "A", "6D"), "recording-test", samples.put):
            time.sleep(track_seconds)
    tracked = []
    while not samples.empty():
        tracked.append(samples.get_nowait())
    out = stop(replay) if replay.poll() is None else replay.communicate()[0]
    return {
        "calibration": calibration,
        "tracked_samples": len(tracked),
        "replay": json_lines(out),
        "replay_status": replay.returncode,
    }


def json_lines(out: str) -> list[dict]:
    """The JSON lines of a command's ``--json`` output."""
    return [json.loads(line) for line in out.splitlines() if line.startswith("{")]


def difference(a: dict, b: dict) -> tuple[float, float]:
    """How far two calibrated poses (``core.to_json`` form) differ: (mm, degrees)."""
    mm = float(np.linalg.norm(np.subtract(a["translation"], b["translation"])) * 1000)
    relative = quaternions.multiply(quaternions.conjugate(np.array(a["rotation"])), b["rotation"])
    return mm, float(np.degrees(quaternions.angle(relative)))
