"""A renderer asks for C->A at its display time, 20 ms ahead of its clock, on the demo's live
flow (agent, simulated A.R.T. and camera, their DTrack adapter, the database serving the true
C->HT), and gets a pose closer to the truth at that time than the latest sample it holds.
The simulator's truth serves only to compute the errors."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bench.calibrated_tracking_bench import scenario_with_true_calibration
from tests.integration.conftest import kill_tagged
from tests.integration.zenoh_helpers import free_port, wait_until
from ubitrack_agent.commands.demo import dtrack_flags, simulator_arguments
from ubitrack_agent.core.errors import ExtrapolationError, NoDataError
from ubitrack_agent.io.application import Relation
from ubitrack_agent.net import config
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.session import open_session
from ubitrack_agent.sim_trackers.scenario import load_scenario

pytestmark = pytest.mark.integration

AHEAD_NS = 20_000_000
ANSWERS = 100


def test_pose_predicted_for_display_beats_the_latest_sample(processes, tmp_path: Path):
    port, art_port = free_port(), free_port()
    domain = f"predict{port}"
    hub = config.Settings(listen=(f"tcp/127.0.0.1:{port}",), domain=domain)
    member = config.member_flags(hub)
    scenario_path = scenario_with_true_calibration(tmp_path)
    scenario = load_scenario(str(scenario_path))
    scenario_flag = ["--scenario", str(scenario_path)]
    simulators = simulator_arguments(scenario_flag, art_port, seed=11)

    def start(*arguments: str) -> None:
        command = [sys.executable, "-m", "ubitrack_agent.cli", *arguments]
        processes.append(subprocess.Popen(command, start_new_session=True))

    start("agent", *config.as_flags(hub))
    with (
        open_session(config.member_of(hub)) as session,
        Relation(
            session, KeySpace(hub.key_prefix), RelationId("C", "A", "6D"), keep_waiting=True
        ) as relation,  # asked before the sensors start
    ):
        start("sim", "database", *scenario_flag, *member)
        start(*simulators["sim camera"], *member)
        start(*simulators["sim art"])
        start("dtrack", *dtrack_flags(scenario.art, art_port), *member)
        relation.wait_for(timeout=90)

        def fused() -> bool:  # the filter answers a time ahead once fusion runs
            try:
                relation.predict(time.time_ns() + AHEAD_NS, timeout=1.0)
            except (ExtrapolationError, NoDataError, TimeoutError):
                return False
            return True

        wait_until(fused, timeout=60, interval=0.2)
        # A renderer in steady state: the flow the agent first planned may still be rewired,
        # and a just-started constant-velocity filter has no velocity to predict with yet.
        time.sleep(3.0)
        # 100 answers, one every 0.1 s: 10 s, half the walk's period (0.05 Hz), over which
        # its squared speed averages as over a whole one. A slow stretch alone favours the
        # held sample (a 2 s window once did: 1.8 against 1.5 mm).
        predicted, held = [], []
        for _ in range(1000):  # a loaded machine may refuse some
            if len(predicted) == ANSWERS:
                break
            display = time.time_ns() + AHEAD_NS
            latest = relation.latest()
            try:
                pose = relation.predict(display, timeout=1.0)
            except (TimeoutError, ExtrapolationError):  # late data on a loaded machine
                time.sleep(0.1)
                continue
            _, truth = scenario.world.pose("C", "A", display)
            predicted.append(np.linalg.norm(pose.translation - truth))
            held.append(np.linalg.norm(latest.translation - truth))
            time.sleep(0.1)
    assert len(predicted) == ANSWERS
    rms_predicted = float(np.sqrt(np.mean(np.square(predicted))))
    rms_held = float(np.sqrt(np.mean(np.square(held))))
    assert rms_predicted < rms_held, (rms_predicted, rms_held)
    kill_tagged(domain)
