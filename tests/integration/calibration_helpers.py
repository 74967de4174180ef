"""Live calibration setups for integration tests: the agent, simulated trackers, a calibration
store and ``ubitrack calibrate``, each a real process on a test's own loopback port and domain.

Two noise-free trackers (``ubitrack_agent.sim_trackers.exact_tracker --hide-world``) see the same
moving head target HT but announce nothing about where they stand, so ``ART -> T2`` is a static
relation only dynamic measurements reveal: ``ART->HT (T2->HT)^-1`` averaged over time. The truth
used to check a result comes from the simulator (:func:`true_art_t2`), never from the system.
"""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tests.integration.zenoh_helpers import free_port, member_flags, wait_until
from ubitrack_agent.core import quaternions, se3
from ubitrack_agent.net import config
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.session import open_session
from ubitrack_agent.net.transport import fetch_latest
from ubitrack_agent.sim_trackers.exact_tracker import tracker_pose

ART, T2 = ("ART", 30.0, 2.0), ("T2", -40.0, -1.0)
"""Tracker frames with their simulated placement (yaw in degrees, x in metres)."""


def true_art_t2() -> tuple[np.ndarray, np.ndarray]:
    """ART->T2 = ART->WT (T2->WT)^-1 from the simulator's placement of the two trackers."""
    return se3.compose(*tracker_pose(*ART[1:]), *se3.invert(*tracker_pose(*T2[1:])))


def pose_error(value: dict, truth: tuple[np.ndarray, np.ndarray]) -> tuple[float, float]:
    """How far a pose in ``core.to_json`` form is from ``truth``: (millimetres, degrees)."""
    q_true, t_true = truth
    error_mm = float(np.linalg.norm(np.array(value["translation"]) - t_true) * 1000)
    relative = quaternions.multiply(quaternions.conjugate(q_true), value["rotation"])
    return error_mm, float(np.degrees(quaternions.angle(relative)))


@dataclass
class LiveCalibration:
    """Processes of one live calibration test; each goes into ``processes`` (the fixture that
    kills them, pass or fail)."""

    processes: list[subprocess.Popen]
    port: int = field(default_factory=free_port)

    @property
    def domain(self) -> str:
        return f"cal{self.port}"

    @property
    def member(self) -> list[str]:
        """Flags making a child process join the test's agent."""
        return member_flags(self.port, self.domain)

    @property
    def hub(self) -> config.Settings:
        return config.Settings(listen=(f"tcp/127.0.0.1:{self.port}",), domain=self.domain)

    def start(self, *command: str) -> subprocess.Popen:
        """A Python process (``-m module ...``) in its own process group."""
        process = subprocess.Popen([sys.executable, *command], start_new_session=True)
        self.processes.append(process)
        return process

    def agent(self) -> subprocess.Popen:
        """The agent (with its host manager and workers in its process group)."""
        agent = ["agent", "--listen", f"tcp/127.0.0.1:{self.port}", "--domain", self.domain]
        return self.start("-m", "ubitrack_agent.cli", *agent)

    def tracker(self, provider: str, placement: tuple[str, float, float], *extra: str) -> None:
        """A noise-free tracker ``placement = (frame, yaw, x)`` (``exact_tracker``)."""
        frame, yaw, x = placement
        tracker = ["--provider", provider, "--tracker", frame, "--yaw", str(yaw), "--x", str(x)]
        self.start(
            "-m", "ubitrack_agent.sim_trackers.exact_tracker", *tracker, *extra, *self.member
        )

    def hidden_trackers(self) -> None:
        """ART and T2, announcing only their view of HT."""
        for provider, placement in (("art", ART), ("t2", T2)):
            self.tracker(provider, placement, "--hide-world")

    def store(self, path: Path) -> subprocess.Popen:
        """A calibration store (``ubitrack store``) serving and saving ``path``."""
        return self.start("-m", "ubitrack_agent.cli", "store", str(path), *self.member)

    def run_calibrate(self, *arguments: str) -> subprocess.CompletedProcess:
        """``ubitrack calibrate --json --wait ARGUMENTS`` to its end (``--timeout 60`` unless
        the arguments give another; at most 90 s): it waits for trackers still starting."""
        command = ["calibrate", "--json", "--wait", "--timeout", "60", *arguments, *self.member]
        return subprocess.run(
            [sys.executable, "-m", "ubitrack_agent.cli", *command],
            capture_output=True,
            text=True,
            timeout=90,
        )

    def calibrate(self, *extra: str) -> list[dict]:
        """``ubitrack calibrate ART T2 EXTRA``, which must succeed: its JSON lines."""
        out = self.run_calibrate("ART", "T2", *extra)
        assert out.returncode == 0, out.stderr[-2000:] + out.stdout[-3000:]
        return [json.loads(line) for line in out.stdout.splitlines()]

    def wait_for_provider(self, session, provider: str) -> None:
        """Until the agent has ``provider`` (e.g. ``store.ART_T2``) in its SRG."""
        keys = KeySpace(self.hub.key_prefix)

        def planned() -> bool:
            replies = fetch_latest(session, keys.agent_status(), timeout=0.5)
            return bool(replies) and provider in json.loads(replies[0]).get("providers", {})

        wait_until(planned, timeout=20)

    def session(self):
        """A zenoh session of the test joining the agent's network (a context manager)."""
        return open_session(config.member_of(self.hub))
