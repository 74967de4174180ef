"""The camera adapter without zenoh: announcements, the measurements of a rendered frame
(names, types, timestamps, covariances) as the simulated camera makes them, what it counts,
the frame loop on a fake capture, and reading the intrinsics."""

from __future__ import annotations

import json
import textwrap
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from bench.marker_images import marker_world, render, true_corners
from ubitrack_agent.core import CameraIntrinsics, Pose, Position2D
from ubitrack_agent.io.camera.adapter import CameraAdapter, metric_sigma
from ubitrack_agent.io.camera.aruco import make_detector
from ubitrack_agent.io.camera.capture import StatusLine, check_frame_size, serve_capture
from ubitrack_agent.io.camera.intrinsics import read_intrinsics
from ubitrack_agent.io.static_edges import StaticEdgesError

T0 = 1_763_700_000_000_000_000
LENGTH = 0.1
CORNER_EDGES = ["IP_M7_0", "IP_M7_1", "IP_M7_2", "IP_M7_3"]


@pytest.fixture(scope="module")
def world():
    return marker_world(0.5, 25, 15)


@pytest.fixture(scope="module")
def frame(world):
    image = render(world, "IP", {"M": 7}, LENGTH, 0)
    return np.dstack([image] * 3)  # BGR, as a webcam gives it


def _adapter(world, **options) -> CameraAdapter:
    intrinsics = CameraIntrinsics(0, world.image_planes["IP"].matrix, np.zeros(5), (640, 480))
    return CameraAdapter("IP", {7: "M7"}, make_detector(), intrinsics, **options)


class Collector:
    def __init__(self) -> None:
        self.published: list[tuple[str, object]] = []

    def publish(self, edge_name, measurement) -> None:
        self.published.append((edge_name, measurement))


def test_announcements_follow_the_simulated_camera(world):
    adapter = _adapter(world, rate=30.0, camera="C", marker_length=LENGTH, sigma_px=0.4)
    edges = {edge.name: edge for edge in adapter.edges}
    assert sorted(edges) == sorted([*CORNER_EDGES, "C_M7"])
    corner = edges["IP_M7_2"]
    assert (corner.source, corner.target, corner.type, corner.static) == ("IP", "M7_2", "2D", False)
    assert corner.rate == 30.0 and corner.sigma == pytest.approx(0.4 * 0.5 / 800.0)
    assert (edges["C_M7"].type, edges["C_M7"].source) == ("6D", "C")
    assert [e.type for e in _adapter(world).edges] == ["2D"] * 4  # no poses unless asked


def test_a_frame_gives_the_corners_and_the_pose_with_the_frames_timestamp(world, frame):
    adapter = _adapter(world, camera="C", marker_length=LENGTH, sigma_px=0.4)
    measurements = dict(adapter.convert(frame, T0))
    assert sorted(measurements) == sorted([*CORNER_EDGES, "C_M7"])
    assert {m.timestamp_ns for m in measurements.values()} == {T0}
    truth, _ = true_corners(world, "IP", "M", LENGTH, 0)
    for k, edge in enumerate(CORNER_EDGES):
        corner = measurements[edge]
        assert isinstance(corner, Position2D)
        assert np.linalg.norm(corner.position - truth[k]) < 0.6
        assert np.allclose(corner.covariance, 0.16 * np.eye(2))
    pose = measurements["C_M7"]
    assert isinstance(pose, Pose)
    assert np.linalg.norm(pose.translation - world.pose("C", "M", 0)[1]) < 0.002
    assert adapter.markers_seen == {7: 1}


def test_unmapped_and_duplicate_markers_are_counted_not_published(world):
    image = render(world, "IP", {"M": 3}, LENGTH, 0)
    adapter = _adapter(world)
    assert adapter.convert(image, T0) == []
    assert adapter.counters["unmapped_marker_3"] == 1
    seven = render(world, "IP", {"M": 7}, LENGTH, 0)
    twice = np.hstack([seven[:, 160:480], seven[:, 160:480]])  # marker 7 printed twice
    assert adapter.convert(twice, T0) == []
    assert adapter.counters["duplicate_marker_7"] == 2  # each detection of it


@pytest.mark.parametrize(
    "bad",
    [
        np.zeros((480, 640), dtype=np.float32),
        np.zeros((480, 640, 2), dtype=np.uint8),
        np.zeros((0, 0), dtype=np.uint8),
        b"not an image",
        None,
    ],
)
def test_a_bad_frame_is_rejected_and_counted(world, bad):
    adapter, out = _adapter(world), Collector()
    assert adapter.handle(bad, T0, out) == 0
    assert adapter.counters["rejected"] == 1 and out.published == []


def test_the_configuration_is_checked(world):
    intrinsics = CameraIntrinsics(0, np.diag([800.0, 800.0, 1.0]))
    with pytest.raises(ValueError, match="no ArUco marker"):
        CameraAdapter("IP", {}, make_detector(), intrinsics)
    with pytest.raises(ValueError, match="side length"):
        CameraAdapter("IP", {7: "M7"}, make_detector(), intrinsics, camera="C")
    with pytest.raises(ValueError, match="named 'IP_M1_0'"):
        CameraAdapter("IP", {1: "M1", 2: "M1"}, make_detector(), intrinsics)
    assert metric_sigma(1.0, 2.0, intrinsics) == pytest.approx(2.0 / 800.0)


class FakeCapture:
    """Frames, then failed reads (``None``), as ``cv2.VideoCapture.read`` returns them."""

    def __init__(self, frames) -> None:
        self.frames = list(frames)

    def read(self):
        frame = self.frames.pop(0) if self.frames else None
        return frame is not None, frame


def test_the_loop_ends_with_the_file_and_counts_bad_frames(world, frame):
    adapter, out = _adapter(world), Collector()
    capture = FakeCapture([frame, np.zeros((4, 4), np.float64), frame])
    lines: list[str] = []
    serve_capture(capture, adapter, out, threading.Event(), from_device=False, report=lines.append)
    assert adapter.counters["received"] == 3 and adapter.counters["rejected"] == 1
    assert len(lines) == 1 and "markers seen: 7 x2; rejected frames: 1" in lines[0]
    assert len(out.published) == 8
    stamps = [m.timestamp_ns for _, m in out.published]
    assert len(set(stamps[:4])) == 1 and stamps[4] > stamps[3]


def test_a_file_is_read_at_its_frame_rate(world, frame):
    adapter, start = _adapter(world), time.monotonic()
    capture = FakeCapture([frame] * 3)
    serve_capture(capture, adapter, Collector(), threading.Event(), False, pace_hz=50.0)
    assert adapter.counters["received"] == 3 and time.monotonic() - start >= 0.06


def test_a_device_is_retried_then_given_up(world, frame):
    adapter = _adapter(world)
    serve_capture(FakeCapture([frame]), adapter, Collector(), threading.Event(), from_device=True)
    assert adapter.counters["read_failed"] == 100


def test_the_status_line(world, frame):
    adapter = _adapter(world)
    status = StatusLine(adapter, 0.0)
    adapter.handle(frame, T0, Collector())
    adapter.handle(frame, T0, Collector())
    assert status.line(2.0) == (
        "camera: 1.0 frames/s, markers seen: 7 x2; rejected frames: 0, failed reads: 0"
    )
    assert "markers seen: none" in status.line(3.0)


class FakeSizes:
    def __init__(self, width, height) -> None:
        self.values = {3: width, 4: height}  # cv2.CAP_PROP_FRAME_WIDTH, _HEIGHT

    def get(self, prop):
        return self.values[prop]


def test_the_frame_size_must_fit_the_intrinsics():
    intrinsics = CameraIntrinsics(0, np.diag([800.0, 800.0, 1.0]), np.zeros(5), (640, 480))
    check_frame_size(FakeSizes(640, 480), intrinsics)
    check_frame_size(FakeSizes(0, 0), intrinsics)  # the source does not tell
    with pytest.raises(ValueError, match="1280x720 px but the intrinsics are for 640x480") as e:
        check_frame_size(FakeSizes(1280, 720), intrinsics)
    # the whole advice, both ways out, not a clause cut off after "the camera's"
    assert str(e.value).endswith(
        "calibrate the camera again at 1280x720 (`ubitrack intrinsics`, docs/camera.md) "
        "or set the camera's resolution to 640x480"
    )


def test_the_intrinsics_come_from_a_static_edges_file(tmp_path: Path):
    path = tmp_path / "camera.yaml"
    path.write_text(
        "provider: webcam-calibration\n"
        "edges:\n"
        "  - {from: C, to: IP, type: intrinsics, matrix: [[600, 0, 320], [0, 600, 240], [0, 0, 1]],"
        " distortion: [0.1, -0.2, 0, 0, 0], image_size: [640, 480]}\n"
    )
    intrinsics = read_intrinsics(path, "C", "IP")
    assert intrinsics.matrix[0, 0] == 600 and tuple(intrinsics.image_size) == (640, 480)
    with pytest.raises(StaticEdgesError, match=r"no intrinsics edge C->IP2 \(edges: \['C->IP'\]"):
        read_intrinsics(path, "C", "IP2")


def _camera(*argv: str) -> int:
    from ubitrack_agent.cli import main

    return main(["camera", *argv])


def test_the_command_exits_2_with_the_reason(tmp_path: Path, capsys):
    intrinsics = tmp_path / "camera.yaml"
    intrinsics.write_text(
        "provider: p\nedges:\n  - {from: C, to: IP, type: intrinsics, "
        "matrix: [[600, 0, 320], [0, 600, 240], [0, 0, 1]], image_size: [640, 480]}\n"
    )
    missing = str(tmp_path / "missing.avi")
    assert _camera(missing, "--intrinsics", str(intrinsics), "--marker", "7") == 2
    assert "OpenCV cannot open file" in capsys.readouterr().err
    video = tmp_path / "one.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10, (320, 240))
    writer.write(np.full((240, 320, 3), 255, np.uint8))
    writer.release()
    assert _camera(str(video), "--intrinsics", str(intrinsics)) == 2
    assert "no marker mapped" in capsys.readouterr().err
    assert _camera(str(video), "--intrinsics", str(intrinsics), "--marker", "7") == 2
    assert "320x240 px but the intrinsics are for 640x480" in capsys.readouterr().err
    assert _camera(str(video), "--intrinsics", str(intrinsics), "--marker", "7", "--pose") == 2
    assert "--pose needs --marker-length" in capsys.readouterr().err


def test_the_webcam_guide_plans_the_markers_pose_by_2d3d_pose_estimation(tmp_path, capsys):
    """docs/camera.md's static-edges file and the camera's announcements: the planner finds
    C->M7 from the four corners, as from the simulated camera's features."""
    from ubitrack_agent.cli import main

    guide = (Path(__file__).resolve().parents[2] / "docs" / "camera.md").read_text()
    block = guide.split("```yaml\n", 1)[1].split("```", 1)[0]
    static = tmp_path / "camera.yaml"
    static.write_text(textwrap.dedent(block))
    intrinsics = read_intrinsics(static, "C", "IP")
    adapter = CameraAdapter("IP", {7: "M7"}, make_detector(), intrinsics)
    setup = {
        "name": "webcam",
        "edges": [
            {"from": e.source, "to": e.target, "type": e.type, "provider": "webcam"}
            for e in adapter.edges
        ],
    }
    (tmp_path / "setup.yaml").write_text(yaml.safe_dump(setup))
    argv = [str(tmp_path / "setup.yaml"), str(static), "--from", "C", "--to", "M7", "--type", "6D"]
    assert main(["plan", *argv, "--json"]) == 0
    (best,) = json.loads(capsys.readouterr().out)["solutions"]
    assert [step["pattern"] for step in best["steps"]] == ["PoseEstimation2D3D"]
    assert ["IP", "M7_3", "2D", "webcam"] in best["measured"]
