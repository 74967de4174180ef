"""Simulators on a host whose clock is off (``--clock-offset-ms``): they measure the world at
real time and stamp on their clock, so a measurement corrected by the offset compares like with
like against the ground truth; the DTrack adapter, on the same clock, passes the controller's
time on exactly."""

from __future__ import annotations

import dataclasses

import numpy as np

from tests.unit.test_sim_art_adapter import Recorder
from ubitrack_agent.io.dtrack.format import encode_frame
from ubitrack_agent.net.clock import Clock
from ubitrack_agent.sim_trackers.scenario import load_scenario
from ubitrack_agent.sim_trackers.sim_art import ArtSimulator, dtrack_adapter
from ubitrack_agent.sim_trackers.sim_camera import CameraSimulator

SCENARIO = load_scenario()
T0 = 1_763_700_000_123_456_000  # real time, whole microseconds
AHEAD = 300_000_000


def test_a_camera_ahead_measures_the_world_now_and_stamps_its_own_time():
    camera = dataclasses.replace(SCENARIO.camera, occlusion=0.0, dropout=0.0)
    offset = CameraSimulator(SCENARIO.world, camera, np.random.default_rng(4), Clock(AHEAD))
    exact = CameraSimulator(SCENARIO.world, camera, np.random.default_rng(4))
    seen, truth = offset.measure(T0), exact.measure(T0)
    assert {sample.timestamp_ns for sample in seen.values()} == {T0 + AHEAD}
    for name, sample in seen.items():
        np.testing.assert_array_equal(sample.position, truth[name].position)


def test_art_and_its_adapter_ahead_stamp_the_real_measurement_on_their_clock():
    art = dataclasses.replace(SCENARIO.art, dropout=0.0)
    clock = Clock(AHEAD + 789)  # not whole microseconds: ts carries microseconds
    simulator = ArtSimulator(SCENARIO.world, art, np.random.default_rng(7), clock)
    exact = ArtSimulator(SCENARIO.world, art, np.random.default_rng(7))
    adapter, recorder = dtrack_adapter(art, "device"), Recorder()
    received_on_its_clock = clock.reading(T0 + 2_000_000)
    adapter.handle(encode_frame(simulator.frame(T0)), received_on_its_clock, recorder)
    (_, wt), (_, ht) = recorder.published
    assert wt.timestamp_ns == ht.timestamp_ns == T0 + AHEAD  # the offset, to the microsecond
    truth = Recorder()
    dtrack_adapter(art, "device").handle(encode_frame(exact.frame(T0)), T0 + 2_000_000, truth)
    np.testing.assert_array_equal(ht.translation, truth.published[1][1].translation)
