"""Simulated A.R.T. and the DTrack adapter, without a network: datagrams in, measurements out."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import RigidTransform, Rotation

from sim_trackers.scenario import load_scenario
from sim_trackers.sim_art import ArtSimulator
from ubitrack_agent.core import ErrorPose, Position3D
from ubitrack_agent.io.dtrack_adapter import DTrackAdapter, announcements
from ubitrack_agent.io.dtrack_format import (
    DAY_NS,
    encode_frame,
    parse_frame,
    seconds_of_day,
    timestamp_from_ts,
)

SCENARIO = load_scenario()
T0 = 1_763_700_000_123_456_000  # a whole number of microseconds


class Recorder:
    def __init__(self) -> None:
        self.published: list[tuple[str, object]] = []

    def publish(self, edge_name, measurement) -> None:
        self.published.append((edge_name, measurement))


def _adapter(art, **kwargs) -> tuple[DTrackAdapter, Recorder]:
    recorder = Recorder()
    adapter = DTrackAdapter(
        recorder,
        art.frame,
        art.bodies,
        art.markers,
        sigma_mm=art.noise.position_mm,
        sigma_deg=art.noise.rotation_deg,
        **kwargs,
    )
    return adapter, recorder


def test_round_trip_through_dtrack_matches_ground_truth_within_noise():
    art = dataclasses.replace(SCENARIO.art, dropout=0.0)
    simulator = ArtSimulator(SCENARIO.world, art, np.random.default_rng(7))
    adapter, recorder = _adapter(art)
    errors_mm, errors_deg, mahalanobis = [], [], []
    for i in range(300):
        t = T0 + i * 16_667_000
        adapter.handle(encode_frame(simulator.frame(t)), received_ns=t + 2_000_000)
        assert [name for name, _ in recorder.published[-2:]] == ["ART_WT", "ART_HT"]
        for name, pose in recorder.published[-2:]:
            assert isinstance(pose, ErrorPose) and pose.timestamp_ns == t
            q, position = SCENARIO.world.pose("ART", name.split("_")[1], t)
            errors_mm.append(1000 * (pose.translation - position))
            delta = Rotation.from_quat(pose.rotation) * Rotation.from_quat(q).inv()
            errors_deg.append(np.degrees(delta.as_rotvec()))
            left = RigidTransform.from_components(
                pose.translation, Rotation.from_quat(pose.rotation)
            )
            xi = (
                left * RigidTransform.from_components(position, Rotation.from_quat(q)).inv()
            ).as_exp_coords()
            mahalanobis.append(xi @ np.linalg.solve(pose.covariance, xi))
    # Per-axis spread equals the configured noise (0.3 mm, 0.05 deg) and DTrack's printed
    # precision adds < 0.001 mm; the reported covariance explains the errors (chi-square
    # with 6 degrees of freedom has mean 6).
    assert np.std(errors_mm, axis=0) == pytest.approx([0.3] * 3, rel=0.15)
    assert np.std(errors_deg, axis=0) == pytest.approx([0.05] * 3, rel=0.15)
    assert np.abs(np.mean(errors_mm, axis=0)).max() < 0.05
    assert np.mean(mahalanobis) == pytest.approx(6.0, rel=0.15)
    assert adapter.counters["malformed"] == 0


def test_dropped_bodies_are_omitted_but_still_calibrated():
    art = dataclasses.replace(SCENARIO.art, dropout=1.0)
    frame = parse_frame(
        encode_frame(ArtSimulator(SCENARIO.world, art, np.random.default_rng(1)).frame(T0))
    )
    assert frame.bodies == () and frame.calibrated_bodies == 2
    adapter, recorder = _adapter(art)
    adapter.handle(encode_frame(frame), T0)
    assert recorder.published == []


def test_markers_become_3d_edges():
    art = dataclasses.replace(SCENARIO.art, dropout=0.0, markers={3: "F1"})
    simulator = ArtSimulator(SCENARIO.world, art, np.random.default_rng(2))
    adapter, recorder = _adapter(art)
    adapter.handle(encode_frame(simulator.frame(T0)), T0)
    name, position = recorder.published[-1]
    assert name == "ART_F1" and isinstance(position, Position3D)
    truth = SCENARIO.world.pose("ART", "F1", T0)[1]
    assert np.linalg.norm(position.position - truth) < 0.003
    edges = announcements("ART", art.bodies, art.static_bodies, art.markers, 60.0, 0.0003)
    assert [(e.name, e.type, e.static) for e in edges] == [
        ("ART_WT", "6D", True),
        ("ART_HT", "6D", False),
        ("ART_F1", "3D", False),
    ]


def test_bad_datagrams_and_unknown_ids_are_counted_not_fatal():
    adapter, recorder = _adapter(SCENARIO.art)
    adapter.handle(b"garbage", T0)
    adapter.handle(b"fr 1\n6d 1 [0 1.0][1 2 3 0 0 0][1 0 0 0 1 0 0 0]", T0)
    adapter.handle(b"fr 2\n6d 1 [9 1.000][1 2 3 0 0 0][1 0 0 0 1 0 0 0 1]\n", T0)
    adapter.handle(b"fr 3\n6d 1 [1 -1.000][0 0 0 0 0 0][1 0 0 0 1 0 0 0 1]\n", T0)
    assert adapter.counters["malformed"] == 2
    assert adapter.counters["unknown_body_9"] == 1
    assert adapter.counters["datagrams"] == 4 and recorder.published == []


def test_receive_time_policy_and_missing_ts():
    adapter, recorder = _adapter(SCENARIO.art, timestamps="receive")
    adapter.handle(b"fr 1\nts 10.0\n6d 1 [1 1.000][1000 0 0 0 0 0][1 0 0 0 1 0 0 0 1]\n", T0)
    assert recorder.published[-1][1].timestamp_ns == T0
    np.testing.assert_array_equal(recorder.published[-1][1].translation, [1.0, 0.0, 0.0])
    adapter, recorder = _adapter(SCENARIO.art)
    adapter.handle(b"fr 1\n6d 1 [1 1.000][1000 0 0 0 0 0][1 0 0 0 1 0 0 0 1]\n", T0)
    assert recorder.published[-1][1].timestamp_ns == T0


@pytest.mark.parametrize(
    ("sample_offset_s", "host_offset_s"),
    [(0.0, 0.0), (86_399.999999, 86_399.999999 + 0.5), (86_399.9, 86_400.2), (0.1, -0.3)],
)
def test_ts_maps_to_the_host_clock_across_midnight(sample_offset_s, host_offset_s):
    midnight = 1_763_683_200 * 1_000_000_000
    assert midnight % DAY_NS == 0
    sample = midnight + round(sample_offset_s * 1e6) * 1000
    host = midnight + round(host_offset_s * 1e9)
    assert timestamp_from_ts(seconds_of_day(sample), host) == sample
