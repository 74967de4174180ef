"""The 3D view's placement of frames (``commands.view.frames``), the keys it follows
(``commands.view.frame_watch``) and the display time (``commands.view.align``): poses composed
and inverted along the fewest hops, positions as leaves, covariances as ellipsoids, the
tracker's frame as the default root, network input filtered, every relation evaluated at one
display time (interpolated, a stopped one held with its skew)."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ubitrack_agent.commands.view.align import Aligned, Recent, align
from ubitrack_agent.commands.view.frame_watch import MAX_KEYS, frames_from, spatial_keys, take
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
            {"id": "db/WT_F1", "from": "WT", "to": "F1", "type": "3D", "static": True},
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
            "inverse": {
                "derives": [["HT", "C", "6D"]],
                "outputs": {"out": f"{data}/inverse/out"},
                "inputs": [{"port": "in", "static": True}],
            },
            "elsewhere": {"derives": [["C", "A", "6D"]], "outputs": {"x": "other/data/x"}},
            "two": {"derives": [["C", "A", "6D"], ["A", "B", "6D"]], "outputs": {"x": f"{data}/t"}},
            "image": {"derives": [["IP", "F", "2D"]], "outputs": {"x": f"{data}/image/x"}},
            "odd": 3,
        },
    }
    assert spatial_keys(status, KEYS) == {
        f"{data}/art/HT": ("ART", "HT", False, "art/HT", False),
        f"{data}/db/WT_F1": ("WT", "F1", False, "db/WT_F1", True),
        f"{data}/fusion-1/fused": ("C", "WT", True, "fusion-1", False),
        f"{data}/inverse/out": ("HT", "C", True, "inverse", True),  # of static inputs only
    }
    many = {
        "srg": [{"id": f"p/e{i}", "from": "A", "to": f"B{i}", "type": "6D"} for i in range(999)]
    }
    assert len(spatial_keys(many, KEYS)) == MAX_KEYS
    assert spatial_keys({"srg": 5, "components": []}, KEYS) == {}


def test_frames_from_decodes_the_samples_and_counts_what_is_no_measurement():
    srg = [{"id": "art/HT", "from": "ART", "to": "HT", "type": "6D", "static": False}]
    key = "ubitrack/demo/data/art/HT"
    wanted = {key: ("ART", "HT", False, "art/HT", False), "k2": ("HT", "X", False, "x", False)}
    payloads = {key: [encode(pose([0, 0, 0], [0, 0, 2.0]))], "k2": [b"\x00not a measurement"]}
    counters: Counter[str] = Counter()
    recent: dict[str, Recent] = {"gone": Recent(False)}
    take(recent, wanted, payloads, counters)
    assert set(recent) == {key, "k2"} and len(recent["k2"]) == 0  # "gone" is no longer wanted
    assert counters["undecodable_samples"] == 1
    placed = frames_from(srg, wanted, recent, None)
    assert (placed["root"], placed["default_root"]) == ("ART", "ART")
    assert placed["frames"]["HT"]["position"] == [0.0, 0.0, 2.0]
    assert placed["frames"]["HT"]["skew_ms"] == 0.0 and placed["behind_ms"] == 0.0
    assert placed["relations"] == {"art/HT": {"mode": "interpolated", "skew_ms": 0.0}}
    assert frames_from(srg, wanted, recent, "HT")["frames"]["ART"]["position"] == [0, 0, -2.0]
    unknown = frames_from(srg, wanted, recent, "NOPE")
    assert unknown == {"error": "no frame 'NOPE' in the SRG", "known": ["ART", "HT"]}
    assert frames_from([], {}, {}, None) == {
        "error": "no frames yet: no agent's status has named an SRG edge",
        "known": [],
    }


MS = 10**6


def moving(t_ms: float, speed: float = 1.0) -> Pose:
    """A pose moving along x at ``speed`` m/s, at ``t_ms``."""
    return Pose(
        int(t_ms * MS), np.array([0.0, 0.0, 0.0, 1.0]), np.array([speed * t_ms / 1e3, 0, 0])
    )


def test_the_frames_are_placed_at_one_display_time_not_from_each_latest_sample():
    """A tracker at 50 Hz (R->A, A moving along x at 1 m/s) and a camera at 25 Hz (A->B, B
    moving along x in A at -1 m/s, so B stays where it started in R): composed at one instant
    B stays put; composed from each relation's latest sample it would be off by the tracker's
    lead over the camera (here 1 m/s * 25 ms = 25 mm)."""
    tracker, camera = Recent(False), Recent(False)
    for t in range(1000, 2001, 20):
        tracker.add(moving(t))  # 50 Hz, up to t = 2000 ms
    for t in range(1015, 2000, 40):
        camera.add(moving(t, speed=-1.0))  # 25 Hz, up to t = 1975 ms
    wanted = {"k/t": ("R", "A", False, "t", False), "k/c": ("A", "B", False, "c", False)}
    srg = [{"id": "t", "from": "R", "to": "A", "type": "6D", "static": False}]
    placed = frames_from(srg, wanted, {"k/t": tracker, "k/c": camera}, "R")
    assert placed["display_time_ns"] == camera.newest_time()
    assert placed["behind_ms"] == pytest.approx(25.0, abs=1e-6)
    assert placed["frames"]["B"]["position"] == pytest.approx([0.0, 0.0, 0.0], abs=1e-9)
    assert placed["frames"]["A"]["position"][0] == pytest.approx(1.975, abs=1e-9)  # at 1975 ms
    assert {r["mode"] for r in placed["relations"].values()} == {"interpolated"}
    # each relation's latest sample instead: 25 mm off, what the alignment removes
    latest = place(
        ["R", "A", "B"],
        [
            relation("R", "A", tracker.latest(), name="t"),
            relation("A", "B", camera.latest(), name="c"),
        ],
        "R",
    )
    assert latest["frames"]["B"]["position"][0] == pytest.approx(0.025, abs=1e-9)


def test_a_stopped_relation_is_held_with_its_skew_and_a_static_one_is_held_without():
    """A relation whose newest sample is older than CURRENT_S does not hold the display time
    back: it is held, its skew shown on the frames it places; a static one has no skew."""
    tracker, stopped, static = Recent(False), Recent(False), Recent(True)
    for t in range(0, 2001, 20):
        tracker.add(moving(t))
    stopped.add(moving(1000))
    static.add(Pose(5, np.array([0.0, 0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0])))
    aligned = align({"tracker": tracker, "stopped": stopped, "static": static})
    assert aligned.display_ns == 2000 * MS == aligned.newest_ns
    assert aligned.relations["tracker"] == Aligned(tracker.latest(), "interpolated", 0)
    assert aligned.relations["stopped"] == Aligned(stopped.latest(), "held", 1000 * MS)
    assert aligned.relations["static"] == Aligned(static.latest(), "static", 0)
    wanted = {
        "tracker": ("R", "A", False, "tracker", False),
        "stopped": ("A", "B", False, "stopped", False),
        "static": ("R", "S", False, "static", True),
    }
    srg = [{"id": "tracker", "from": "R", "to": "A", "type": "6D", "static": False}]
    recent = {"tracker": tracker, "stopped": stopped, "static": static}
    frames = frames_from(srg, wanted, recent, "R")["frames"]
    assert (frames["A"]["skew_ms"], frames["B"]["skew_ms"], frames["S"]["skew_ms"]) == (0, 1000, 0)
    assert align({"static": static}).display_ns is None


def test_a_relation_whose_samples_do_not_reach_the_display_time_takes_its_nearest():
    fast, slow = Recent(False, history=4), Recent(False)
    for t in range(100, 201, 10):
        fast.add(moving(t))  # keeps 170..200 ms
    slow.add(moving(150))
    aligned = align({"fast": fast, "slow": slow})
    assert aligned.display_ns == 150 * MS
    assert aligned.relations["fast"].value.timestamp_ns == 170 * MS
    assert aligned.relations["fast"].skew_ns == 20 * MS
    fast.add(moving(90))  # older than all of a full history: dropped
    assert fast.at(90 * MS)[0].timestamp_ns == 170 * MS
    fast.add(moving(185))  # out of order, inserted in place
    assert fast.at(185 * MS) == (fast.at(185 * MS)[0], 0)
    assert fast.at(185 * MS)[0].translation[0] == pytest.approx(0.185)


@pytest.mark.parametrize("root", ["R", "A"])
def test_the_root_is_at_the_origin_unrotated(root):
    frames = place(["R", "A"], [relation("R", "A", pose([1, 2, 3], [4, 5, 6]))], root)["frames"]
    assert frames[root]["position"] == [0.0, 0.0, 0.0] and frames[root]["via"] == []
    assert frames[root]["rotation"] == [0.0, 0.0, 0.0, 1.0]
