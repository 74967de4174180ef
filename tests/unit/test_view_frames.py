"""The 3D view's placement of frames (``commands.view.frames``) and the keys it follows
(``commands.view.frame_watch``): poses composed and inverted along the fewest hops, positions as
leaves, covariances as ellipsoids, the tracker's frame as the default root, network input
filtered."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ubitrack_agent.commands.view.frame_watch import MAX_KEYS, frames_from, spatial_keys
from ubitrack_agent.commands.view.frames import (
    LiveRelation,
    ellipsoid,
    place,
    srg_frames,
    tracker_frame,
)
from ubitrack_agent.core.codec import encode
from ubitrack_agent.core.measurements import ErrorPose, Pose, Position2D, Position3D
from ubitrack_agent.net.keys import KeySpace

KEYS = KeySpace("ubitrack/demo")


def pose(rotvec: list[float], translation: list[float], covariance=None) -> Pose | ErrorPose:
    q = Rotation.from_rotvec(rotvec).as_quat()
    if covariance is None:
        return Pose(1, q, np.array(translation, dtype=float))
    return ErrorPose(1, q, np.array(translation, dtype=float), np.array(covariance))


def matrix(sample: Pose | ErrorPose) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(sample.rotation).as_matrix()
    m[:3, 3] = sample.translation
    return m


def relation(source, target, sample, derived=False, name=None) -> LiveRelation:
    return LiveRelation(source, target, sample, derived, name or f"{source}_{target}")


def test_frames_are_placed_by_composing_and_inverting_poses_along_the_fewest_hops():
    r_a = pose([0, 0, 0.5], [1.0, 0.0, 0.0])
    b_a = pose([0.3, 0.1, 0.0], [0.0, 2.0, 0.5])  # B->A: walked backwards from A
    b_p = Position3D(1, np.array([0.1, 0.2, 0.3]))
    placed = place(
        ["R", "A", "B", "P", "IP", "LOST"],
        [
            relation("R", "A", r_a),
            relation("B", "A", b_a),
            relation("B", "P", b_p),
            relation("IP", "P", Position2D(1, np.array([3.0, 4.0]))),
        ],
        "R",
    )
    frames = placed["frames"]
    assert set(frames) == {"R", "A", "B", "P"}
    expected_b = matrix(r_a) @ np.linalg.inv(matrix(b_a))
    np.testing.assert_allclose(frames["B"]["position"], expected_b[:3, 3], atol=1e-6)
    rotation = Rotation.from_quat(frames["B"]["rotation"]).as_matrix()
    np.testing.assert_allclose(rotation, expected_b[:3, :3], atol=1e-5)
    np.testing.assert_allclose(
        frames["P"]["position"], (expected_b @ [0.1, 0.2, 0.3, 1])[:3], atol=1e-6
    )
    assert frames["P"]["rotation"] is None  # a position: no axes
    assert frames["B"]["via"] == ["R_A", "B_A inverted"]
    assert frames["P"]["via"] == ["R_A", "B_A inverted", "B_P"]
    assert set(placed["unplaced"]) == {"IP", "LOST"}
    assert "no live 6D or 3D relation" in placed["unplaced"]["LOST"]
    assert "no live 6D or 3D relation" in placed["unplaced"]["IP"]  # a 2D edge only
    island = place(["R", "X", "Y"], [relation("X", "Y", r_a)], "R")["unplaced"]
    assert island == dict.fromkeys(
        ("X", "Y"), "its live 6D and 3D relations do not connect it to the root"
    )


def test_of_equally_short_paths_a_components_output_is_taken():
    measured = relation("R", "C", pose([0, 0, 0], [1.0, 0, 0]), name="tracker")
    fused = relation("R", "C", pose([0, 0, 0], [1.1, 0, 0]), derived=True, name="fusion-1")
    for order in ([measured, fused], [fused, measured]):
        frames = place(["R", "C"], order, "R")["frames"]
        assert frames["C"]["via"] == ["fusion-1"]
        assert frames["C"]["position"] == [1.1, 0.0, 0.0]
    longer = [relation("R", "X", pose([0, 0, 0], [0, 0, 0]), derived=True), measured]
    longer.append(relation("X", "C", pose([0, 0, 0], [5.0, 0, 0]), derived=True))
    assert place(["R", "C"], longer, "R")["frames"]["C"]["via"] == ["tracker"]  # one hop


def test_the_uncertainty_is_the_positions_covariance_carried_to_the_root():
    covariance = np.diag([0.0, 0.0, 0.0, 1e-6, 4e-6, 9e-6])  # translation sigmas 1, 2, 3 mm
    turn = pose([0, 0, np.pi / 2], [0.0, 0.0, 0.0])  # R->A: a quarter turn about z
    frames = place(
        ["R", "A", "B"],
        [relation("R", "A", turn), relation("A", "B", pose([0, 0, 0], [1, 0, 0], covariance))],
        "R",
    )["frames"]
    assert frames["A"]["ellipsoid"] is None  # exact
    shape = frames["B"]["ellipsoid"]
    np.testing.assert_allclose(shape["radii"], [1e-3, 2e-3, 3e-3], atol=1e-9)
    # the 2 mm axis (A's y) lies along R's x after the quarter turn
    np.testing.assert_allclose(np.abs(shape["axes"][1]), [1.0, 0.0, 0.0], atol=1e-6)


def test_an_ellipsoid_rebuilds_its_covariance():
    rng = np.random.default_rng(3)
    for _ in range(20):
        a = rng.normal(size=(3, 3))
        covariance = a @ a.T
        shape = ellipsoid(covariance)
        axes = np.array(shape["axes"]).T  # the axes as columns: a rotation
        np.testing.assert_allclose(np.linalg.det(axes), 1.0, atol=1e-5)
        rebuilt = axes @ np.diag(np.square(shape["radii"])) @ axes.T
        np.testing.assert_allclose(rebuilt, covariance, rtol=1e-4, atol=1e-5)
    assert ellipsoid(None) is None


def test_the_default_root_is_the_trackers_frame():
    srg = [
        {"from": "WT", "to": "F1", "type": "3D", "static": True},
        {"from": "C", "to": "IP", "type": "3x4", "static": True},
        {"from": "IP", "to": "F1", "type": "2D", "static": False},
        {"from": "IP", "to": "F2", "type": "2D", "static": False},
        {"from": "ART", "to": "WT", "type": "6D", "static": True},
        {"from": "ART", "to": "HT", "type": "6D", "static": False},
    ]
    assert tracker_frame(srg) == "ART"
    assert tracker_frame(srg[:5]) == "ART"  # no dynamic 6D edge: the most 6D edges
    assert tracker_frame(srg[:4]) == "IP"  # no 6D edge: the most edges
    assert tracker_frame([]) is None
    assert srg_frames([*srg, "odd", {"from": 3}]) == ["ART", "C", "F1", "F2", "HT", "IP", "WT"]


def test_only_spatial_relations_under_this_root_are_followed():
    data = "ubitrack/demo/data"
    status = {
        "srg": [
            {"id": "art/HT", "from": "ART", "to": "HT", "type": "6D"},
            {"id": "db/WT_F1", "from": "WT", "to": "F1", "type": "3D"},
            {"id": "cam/IP_F1", "from": "IP", "to": "F1", "type": "2D"},
            {"id": "bad/**", "from": "A", "to": "B", "type": "6D"},
            {"id": 5, "from": "A", "to": "B", "type": "6D"},
            "odd",
        ],
        "components": {
            "fusion-1": {
                "derives": [["C", "WT", "6D"]],
                "outputs": {"fused": f"{data}/fusion-1/fused"},
            },
            "elsewhere": {"derives": [["C", "A", "6D"]], "outputs": {"x": "other/data/x"}},
            "two": {"derives": [["C", "A", "6D"], ["A", "B", "6D"]], "outputs": {"x": f"{data}/t"}},
            "image": {"derives": [["IP", "F", "2D"]], "outputs": {"x": f"{data}/image/x"}},
            "odd": 3,
        },
    }
    assert spatial_keys(status, KEYS) == {
        f"{data}/art/HT": ("ART", "HT", False, "art/HT"),
        f"{data}/db/WT_F1": ("WT", "F1", False, "db/WT_F1"),
        f"{data}/fusion-1/fused": ("C", "WT", True, "fusion-1"),
    }
    many = {
        "srg": [{"id": f"p/e{i}", "from": "A", "to": f"B{i}", "type": "6D"} for i in range(999)]
    }
    assert len(spatial_keys(many, KEYS)) == MAX_KEYS
    assert spatial_keys({"srg": 5, "components": []}, KEYS) == {}


def test_frames_from_decodes_the_latest_samples_and_counts_what_is_no_measurement():
    srg = [{"id": "art/HT", "from": "ART", "to": "HT", "type": "6D", "static": False}]
    key = "ubitrack/demo/data/art/HT"
    wanted = {key: ("ART", "HT", False, "art/HT"), "k2": ("HT", "X", False, "x")}
    latest = {key: encode(pose([0, 0, 0], [0, 0, 2.0])), "k2": b"\x00not a measurement"}
    counters: Counter[str] = Counter()
    placed = frames_from(srg, wanted, latest, None, counters)
    assert (placed["root"], placed["default_root"]) == ("ART", "ART")
    assert placed["frames"]["HT"]["position"] == [0.0, 0.0, 2.0]
    assert counters["undecodable_samples"] == 1
    assert frames_from(srg, wanted, latest, "HT", counters)["frames"]["ART"]["position"] == [
        0.0,
        0.0,
        -2.0,
    ]
    unknown = frames_from(srg, wanted, latest, "NOPE", counters)
    assert unknown == {"error": "no frame 'NOPE' in the SRG", "known": ["ART", "HT"]}
    assert frames_from([], {}, {}, None, counters) == {
        "error": "no frames yet: no agent's status has named an SRG edge",
        "known": [],
    }


@pytest.mark.parametrize("root", ["R", "A"])
def test_the_root_is_at_the_origin_unrotated(root):
    frames = place(["R", "A"], [relation("R", "A", pose([1, 2, 3], [4, 5, 6]))], root)["frames"]
    assert frames[root]["position"] == [0.0, 0.0, 0.0] and frames[root]["via"] == []
    assert frames[root]["rotation"] == [0.0, 0.0, 0.0, 1.0]
