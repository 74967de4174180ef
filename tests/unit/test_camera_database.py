"""Simulated camera measurements and the calibration database's edges (its file format:
``test_static_edges.py``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ubitrack_agent.core import CameraIntrinsics, Pose, Position3D, Projection
from ubitrack_agent.sim_trackers.database import static_edges
from ubitrack_agent.sim_trackers.scenario import DatabaseEdge, load_scenario
from ubitrack_agent.sim_trackers.sim_camera import CameraSimulator, announcements

SCENARIO = load_scenario()
WORLD = SCENARIO.world
T0 = 1_763_700_000_000_000_000


def test_camera_features_scatter_around_the_projected_truth_with_the_set_noise():
    camera = dataclasses.replace(SCENARIO.camera, occlusion=0.0)
    simulator = CameraSimulator(WORLD, camera, np.random.default_rng(4))
    errors = []
    for i in range(200):
        t = T0 + i * 33_333_333
        measured = simulator.measure(t)
        assert set(measured) == {f"IP_{f}" for f in camera.features}
        truth = WORLD.project("IP", camera.features, t)
        for name, sample in measured.items():
            assert sample.timestamp_ns == t
            errors.append(sample.position - truth[name.removeprefix("IP_")])
    assert np.std(errors, axis=0) == pytest.approx([0.5, 0.5], rel=0.1)
    assert np.abs(np.mean(errors, axis=0)).max() < 0.05
    edges = announcements(camera, WORLD)
    assert [(e.name, e.type, e.static) for e in edges] == [
        (f"IP_{f}", "2D", False) for f in camera.features
    ]
    # 0.5 px at about 2 m with f = 700 px: a metric error of about 1.4 mm, not 0.5 m.
    assert 0.0005 < edges[0].sigma < 0.005


def test_camera_occlusion_and_dropout():
    hidden = dataclasses.replace(SCENARIO.camera, occlusion=0.5)
    simulator = CameraSimulator(WORLD, hidden, np.random.default_rng(5))
    counts = [len(simulator.measure(T0 + i * 33_333_333)) for i in range(400)]
    assert np.mean(counts) == pytest.approx(2.5, rel=0.1)
    lost = dataclasses.replace(SCENARIO.camera, dropout=1.0)
    assert CameraSimulator(WORLD, lost, np.random.default_rng(5)).measure(T0) == {}


def test_database_values_are_the_world_truth():
    served = (*SCENARIO.database_edges, DatabaseEdge("C", "HT", "6D"))  # a calibrated database
    edges = {e.announcement.name: e for e in static_edges(WORLD, served, T0)}
    assert all(e.announcement.static for e in edges.values())
    assert isinstance(edges["C_IP"].value, Projection)
    np.testing.assert_array_equal(
        edges["C_IP"].value.matrix, [[700, 0, 320, 0], [0, 700, 240, 0], [0, 0, 1, 0]]
    )
    assert isinstance(edges["C_HT"].value, Pose)
    np.testing.assert_allclose(edges["C_HT"].value.translation, WORLD.pose("C", "HT", 0)[1])
    assert isinstance(edges["WT_F2"].value, Position3D)
    np.testing.assert_allclose(edges["WT_F2"].value.position, [0.0, 0.22, -0.14])
    (intrinsics,) = static_edges(WORLD, (DatabaseEdge("C", "IP", "intrinsics"),), T0)
    assert intrinsics.announcement.name == "C_IP_intrinsics"
    assert isinstance(intrinsics.value, CameraIntrinsics)
    assert intrinsics.value.image_size == (640, 480)
