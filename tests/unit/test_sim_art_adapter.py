"""Simulated A.R.T. and the DTrack adapter, without a network: datagrams in, measurements out."""

from __future__ import annotations

import dataclasses
import logging
import re

import numpy as np
import pytest
from scipy.spatial.transform import RigidTransform, Rotation

from ubitrack_agent.core import ErrorPose, Position3D
from ubitrack_agent.io.dtrack.adapter import DTrackAdapter
from ubitrack_agent.io.dtrack.format import (
    DAY_NS,
    encode_frame,
    parse_frame,
    seconds_of_day,
    timestamp_from_ts,
)
from ubitrack_agent.sim_trackers.scenario import load_scenario
from ubitrack_agent.sim_trackers.sim_art import ArtSimulator, dtrack_adapter

SCENARIO = load_scenario()
T0 = 1_763_700_000_123_456_000  # a whole number of microseconds


class Recorder:
    def __init__(self) -> None:
        self.published: list[tuple[str, object]] = []
        self.left_out: list[str] = []

    def publish(self, edge_name, measurement) -> None:
        self.published.append((edge_name, measurement))

    def missed(self, edge_name) -> None:
        self.left_out.append(edge_name)


def _adapter(art, timestamps="device") -> tuple[DTrackAdapter, Recorder]:
    return dtrack_adapter(art, timestamps), Recorder()


def test_round_trip_through_dtrack_matches_ground_truth_within_noise():
    art = dataclasses.replace(SCENARIO.art, dropout=0.0)
    simulator = ArtSimulator(SCENARIO.world, art, np.random.default_rng(7))
    adapter, recorder = _adapter(art)
    errors_mm, errors_deg, mahalanobis = [], [], []
    for i in range(300):
        t = T0 + i * 16_667_000
        adapter.handle(encode_frame(simulator.frame(t)), t + 2_000_000, recorder)
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
    assert adapter.counters["rejected"] == 0
    assert adapter.counters["published"] == 600 == 2 * adapter.counters["received"]


def test_dropped_bodies_are_omitted_but_still_calibrated():
    art = dataclasses.replace(SCENARIO.art, dropout=1.0)
    frame = parse_frame(
        encode_frame(ArtSimulator(SCENARIO.world, art, np.random.default_rng(1)).frame(T0))
    )
    assert frame.bodies == () and frame.calibrated_bodies == 2
    adapter, recorder = _adapter(art)
    adapter.handle(encode_frame(frame), T0, recorder)
    assert recorder.published == []


def test_markers_become_3d_edges():
    art = dataclasses.replace(SCENARIO.art, dropout=0.0, markers={3: "F1"})
    simulator = ArtSimulator(SCENARIO.world, art, np.random.default_rng(2))
    adapter, recorder = _adapter(art)
    adapter.handle(encode_frame(simulator.frame(T0)), T0, recorder)
    name, position = recorder.published[-1]
    assert name == "ART_F1" and isinstance(position, Position3D)
    truth = SCENARIO.world.pose("ART", "F1", T0)[1]
    assert np.linalg.norm(position.position - truth) < 0.003
    # A body's sigma counts its rotation noise at a 1 m lever arm: sqrt(3 (0.3 mm)^2 +
    # 3 (0.05 deg in rad x 1 m)^2); a marker's is its position noise.
    body_sigma = (3 * 0.0003**2 + 3 * np.radians(0.05) ** 2) ** 0.5
    assert [(e.name, e.type, e.static, e.rate) for e in adapter.edges] == [
        ("ART_WT", "6D", True, 60.0),  # measured again each frame
        ("ART_HT", "6D", False, 60.0),
        ("ART_F1", "3D", False, 60.0),
    ]
    sigmas = [e.sigma for e in adapter.edges]
    assert sigmas == pytest.approx([body_sigma, body_sigma, 0.0003])


def test_bad_datagrams_and_unmapped_ids_are_counted_not_fatal(caplog):
    caplog.set_level(logging.INFO, logger="ubitrack.adapter")
    adapter, recorder = _adapter(SCENARIO.art)
    for datagram in (
        b"garbage",
        b"fr 1\n6d 1 [0 1.0][1 2 3 0 0 0][1 0 0 0 1 0 0 0]",
        b"fr 2\n6d 1 [9 1.000][1 2 3 0 0 0][1 0 0 0 1 0 0 0 1]\n",
        b"fr 3\n6d 1 [9 1.000][1 2 3 0 0 0][1 0 0 0 1 0 0 0 1]\n",
        b"fr 4\n6d 1 [1 -1.000][0 0 0 0 0 0][1 0 0 0 1 0 0 0 1]\n",
    ):
        adapter.handle(datagram, T0, recorder)
    assert adapter.counters == {"received": 5, "rejected": 2, "unmapped_body_9": 2}
    assert recorder.published == []
    assert "DTrack: rejected input (2 so far): malformed datagram: 6d body 0 matrix" in caplog.text
    assert caplog.text.count("body id 9 is not mapped") == 1  # logged once, counted always


def test_receive_time_policy_and_missing_ts():
    adapter, recorder = _adapter(SCENARIO.art, timestamps="receive")
    adapter.handle(
        b"fr 1\nts 10.0\n6d 1 [1 1.000][1000 0 0 0 0 0][1 0 0 0 1 0 0 0 1]\n", T0, recorder
    )
    assert recorder.published[-1][1].timestamp_ns == T0
    np.testing.assert_array_equal(recorder.published[-1][1].translation, [1.0, 0.0, 0.0])
    adapter, recorder = _adapter(SCENARIO.art, timestamps="device")
    adapter.handle(b"fr 1\n6d 1 [1 1.000][1000 0 0 0 0 0][1 0 0 0 1 0 0 0 1]\n", T0, recorder)
    assert recorder.published[-1][1].timestamp_ns == T0


@pytest.mark.parametrize(
    ("mapping", "message"),
    [
        ({"bodies": {}}, "no DTrack body, tool, Flystick or marker is mapped"),
        ({"bodies": {-1: "HT"}}, "Flystick ids count from 0 and marker ids from 1"),
        ({"bodies": {0: "HT"}, "markers": {0: "F1"}}, "ids count from 0 and marker ids"),
        ({"bodies": {}, "tools": {-1: "P"}}, "ids count from 0 and marker ids"),
        ({"bodies": {0: "HT"}, "flysticks": {0: "HT"}}, "two edges would be named 'ART_HT'"),
        ({"bodies": {0: "HT"}, "static_bodies": ("WT",)}, "static body 'WT' is not a mapped"),
        ({"bodies": {0: "HT", 1: "HT"}}, "two edges would be named 'ART_HT'"),
        ({"bodies": {0: "H/T"}}, "H/T"),
        ({"bodies": {0: "HT"}, "sigma_mm": -1.0}, "noise sigmas must be >= 0"),
        ({"bodies": {0: "HT"}, "timestamps": "ts"}, "timestamp policy 'ts' is not one of"),
    ],
)
def test_inconsistent_mappings_are_refused(mapping, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        DTrackAdapter("ART", **mapping)


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
