"""Scenario files: the default loads, and every kind of mistake is named with file and field."""

from __future__ import annotations

import copy
import re

import pytest
import yaml

from ubitrack_agent.sim_trackers.scenario import DEFAULT_SCENARIO, ScenarioError, load_scenario

BASE = yaml.safe_load(DEFAULT_SCENARIO.read_text(encoding="utf-8"))


def test_default_scenario_is_the_paper_figure_one_setup():
    scenario = load_scenario()
    assert set(scenario.world.frames) == {"ART", "WT", "F1", "F2", "F3", "F4", "F5", "HT", "C", "A"}
    assert scenario.world.image_planes["IP"].camera == "C"
    assert scenario.art.bodies == {0: "WT", 1: "HT"} and scenario.art.static_bodies == ("WT",)
    assert scenario.camera.features == ("F1", "F2", "F3", "F4", "F5")
    edges = {(e.source, e.target, e.type) for e in scenario.database_edges}
    assert ("C", "IP", "3x4") in edges
    assert ("C", "HT", "6D") not in edges  # calibrated live (section 4.2), as a user would
    assert ("WT", "A", "6D") in edges and ("WT", "F5", "3D") in edges


def _write(tmp_path, data) -> str:
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return str(path)


def _set(data, dotted: str, value):
    keys = dotted.split(".")
    for key in keys[:-1]:
        data = data[int(key) if isinstance(data, list) else key]
    if value is _DELETE:
        del data[keys[-1]]
    else:
        data[keys[-1]] = value


_DELETE = object()


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("colour", "red", "scenario: unknown field(s) ['colour']"),
        ("art.nosie", 1, "art: unknown field(s) ['nosie']"),
        ("art.noise.position_mm", "x", "art.noise.position_mm: must be a number"),
        ("art.noise.position_mm", -1, "art.noise.position_mm: must be a number"),
        ("art.rate", _DELETE, "art: missing field(s) ['rate']"),
        ("art.port", 70000, "art.port: must be an integer"),
        ("art.bodies", {0: "WT", 1: "XX"}, "art.bodies.1: unknown frame 'XX'"),
        ("art.static_bodies", ["HT", "C"], "art.static_bodies[1]: 'C' is not one of art.bodies"),
        ("art.dropout", 1.5, "art.dropout: must be a number in [0.0, 1.0]"),
        ("frames.WT.euler_deg", [1, 2], "frames.WT.euler_deg: must be a list of 3 numbers"),
        ("frames.WT.rotation", [0, 0, 0, 1], "frames.WT: give rotation"),
        ("frames.F1.parent", "nowhere", "unknown parent 'nowhere'"),
        ("frames.HT.trajectory.type", "spiral", "frames.HT.trajectory.type: must be 'lissajous'"),
        ("frames.HT.trajectory.speed", 2, "frames.HT.trajectory: unknown field(s) ['speed']"),
        ("frames.ART.parent", "WT", "exactly one root"),
        ("frames.bad/name", {"parent": "ART"}, "frames.bad/name: not a valid name"),
        ("image_planes.IP.image_size", [640], "image_planes.IP.image_size: must be [width, h"),
        ("image_planes.IP.distortion", [0.1, 0.2], "image_planes.IP.distortion: must be a list"),
        ("image_planes.IP.intrinsics.fx", 0, "image_planes.IP.intrinsics.fx: must be a number"),
        ("camera.image_plane", "IQ", "camera.image_plane: unknown image plane 'IQ'"),
        ("camera.features", [], "camera.features: must be a non-empty list"),
        ("database.edges.0.type", "9D", "database.edges[0].type: must be one of"),
        ("database.edges.1.from", "C", "database.edges[1]: C->F1 moves"),
        ("database.edges.0.from", "WT", "database.edges[0]: 'IP' is not an image plane of camera"),
        ("seed", -3, "seed: must be an integer"),
    ],
)
def test_mistakes_are_named_with_file_and_field(tmp_path, field, value, message):
    data = copy.deepcopy(BASE)
    _set(data, field, value)
    path = _write(tmp_path, data)
    with pytest.raises(ScenarioError, match=re.escape(path) + ".*" + re.escape(message)):
        load_scenario(path)


def test_a_rotation_typed_with_four_decimals_is_normalised(tmp_path):
    data = copy.deepcopy(BASE)
    data["frames"]["F1"]["rotation"] = [0.7071, 0.0, 0.0, 0.7071]  # norm 0.99999040
    placement = load_scenario(_write(tmp_path, data)).world.frames["F1"].placement
    assert placement.rotation == pytest.approx((0.5**0.5, 0.0, 0.0, 0.5**0.5), abs=1e-15)
    data["frames"]["F1"]["rotation"] = [0.7, 0.0, 0.0, 0.7]  # norm 0.98995
    with pytest.raises(ScenarioError, match=r"frames\.F1\.rotation: .*normalise it"):
        load_scenario(_write(tmp_path, data))


def test_unreadable_and_invalid_yaml(tmp_path):
    with pytest.raises(ScenarioError, match="cannot read"):
        load_scenario(tmp_path / "missing.yaml")
    (tmp_path / "broken.yaml").write_text("frames: [", encoding="utf-8")
    with pytest.raises(ScenarioError, match="not valid YAML"):
        load_scenario(tmp_path / "broken.yaml")
    (tmp_path / "list.yaml").write_text("- 1\n", encoding="utf-8")
    with pytest.raises(ScenarioError, match="scenario: must be a mapping"):
        load_scenario(tmp_path / "list.yaml")
