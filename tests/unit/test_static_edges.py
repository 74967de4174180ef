"""Static-edges files: round trips, strict validation naming file, entry and field, and atomic
writing (temporary file in the same directory, flush, fsync, rename, directory fsync)."""

from __future__ import annotations

import os
import re
from dataclasses import replace

import numpy as np
import pytest
import yaml

from ubitrack_agent.core import ErrorPose, Pose, Position2D, Position3D
from ubitrack_agent.io import static_edges as static_edges_module
from ubitrack_agent.io.static_edges import (
    StaticEdge,
    StaticEdgesError,
    announced_sigma,
    format_static_edges,
    parse_static_edges,
    read_static_edges,
    static_announcement,
    write_static_edges,
)
from ubitrack_agent.sim_trackers.database import static_edges
from ubitrack_agent.sim_trackers.scenario import DatabaseEdge, load_scenario

SCENARIO = load_scenario()
T0 = 1_763_700_000_000_000_000
T1 = T0 + 5


def scenario_edges() -> list[StaticEdge]:
    """The default scenario's database edges plus an intrinsics edge: every type."""
    extra = DatabaseEdge("C", "IP", "intrinsics")
    return static_edges(SCENARIO.world, (*SCENARIO.database_edges, extra), T0)


def test_round_trip_of_every_type(tmp_path):
    edges = scenario_edges()
    calibrated = np.diag([1e-6] * 3 + [4e-8] * 3)  # e.g. a hand-eye result's covariance
    edges.append(
        StaticEdge(
            static_announcement("HT", "X", "6D"),
            ErrorPose(T0, [0, 0, 0, 1], [0.1, 0.2, 0.3], calibrated),
        )
    )
    path = tmp_path / "calib.yaml"
    write_static_edges(path, "calib", edges)
    provider, loaded = read_static_edges(path, T1)
    assert provider == "calib"
    assert [e.announcement for e in loaded] == [e.announcement for e in edges]
    assert {e.announcement.name for e in loaded} >= {"C_IP", "C_IP_intrinsics", "WT_F1", "HT_X"}
    assert all(e.announcement.static for e in loaded)
    # the file keeps no time: the values are stamped on reading
    assert [e.value for e in loaded] == [replace(e.value, timestamp_ns=T1) for e in edges]
    assert type(loaded[-1].value) is ErrorPose  # a 6D entry with a covariance


def test_a_served_edge_announces_the_sigma_of_its_covariance():
    pose_covariance = np.diag([1e-6] * 3 + [4e-8] * 3)  # rotation (rad^2) first, then metres^2
    pose = ErrorPose(T0, [0, 0, 0, 1], [0, 0, 0], pose_covariance)
    assert announced_sigma(pose) == pytest.approx((3e-6 + 1.2e-7) ** 0.5)  # at a 1 m lever arm
    assert announced_sigma(Position3D(T0, [1, 2, 3], np.eye(3) * 1e-6)) == pytest.approx(3e-6**0.5)
    assert announced_sigma(Pose(T0, [0, 0, 0, 1], [0, 0, 0])) is None  # the planner's default
    edge = StaticEdge(static_announcement("C", "HT", "6D"), pose)
    assert edge.served_announcement() == replace(edge.announcement, sigma=announced_sigma(pose))


def test_the_documented_example_reads():
    example = static_edges_module.__doc__.split("::\n", 1)[1].split("\n\n", 1)[0]
    provider, edges = parse_static_edges(yaml.safe_load(example), T0, "docstring")
    assert provider == "database"
    assert [e.announcement.name for e in edges] == ["C_HT", "WT_F1", "C_IP", "C_IP_intrinsics"]


VALID_6D = {"from": "C", "to": "HT", "type": "6D", "rotation": [0, 0, 0, 1], "translation": [0] * 3}


@pytest.mark.parametrize(
    ("document", "message"),
    [
        ([], "file: must be a mapping with provider and edges"),
        ({"provider": "db"}, "file: missing field(s) ['edges']"),
        ({"provider": "db", "edges": [], "name": "x"}, "file: unknown field(s) ['name']"),
        ({"provider": "db", "edges": []}, "edges: must be a non-empty list"),
        ({"provider": "d/b", "edges": [VALID_6D]}, "provider: not a valid name"),
        ({"provider": "db", "edges": ["C->HT"]}, "edges[0]: must be a mapping with from, to"),
        (
            {"provider": "db", "edges": [VALID_6D | {"type": "9D"}]},
            "edges[0].type: must be one of ['6D', '3D', '3x4', 'intrinsics'], got '9D'",
        ),
        (
            {"provider": "db", "edges": [VALID_6D | {"type": ["6D"]}]},
            "edges[0].type: must be one of",
        ),
        (
            {"provider": "db", "edges": [{"from": "C", "to": "HT", "type": "6D", "rotation": [0]}]},
            "edges[0]: missing field(s) ['translation']",
        ),
        (
            {"provider": "db", "edges": [VALID_6D | {"position": [1, 2, 3]}]},
            "edges[0]: unknown field(s) ['position']",
        ),
        (
            {"provider": "db", "edges": [VALID_6D | {"from": "W/x"}]},
            "edges[0].from: not a valid name",
        ),
        (
            {"provider": "db", "edges": [VALID_6D | {"rotation": [0, 0, 0, 2]}]},
            "edges[0] (C->HT 6D): Pose.rotation: not a unit quaternion (norm 2, more than 0.001 "
            "from 1): normalise it",
        ),
        (
            {"provider": "db", "edges": [VALID_6D | {"translation": [0, True, 0]}]},
            "edges[0] (C->HT 6D): translation: must be a list of numbers",
        ),
        (
            {"provider": "db", "edges": [VALID_6D | {"translation": "0 0 0"}]},
            "edges[0] (C->HT 6D): translation: must be a list of numbers",
        ),
        (
            {"provider": "db", "edges": [VALID_6D | {"covariance": np.eye(6).tolist()[:5]}]},
            "edges[0] (C->HT 6D): ErrorPose.covariance: shape must be 6x6",
        ),
        (
            {"provider": "db", "edges": [{"from": "W", "to": "F", "type": "3D", "position": [1]}]},
            "edges[0] (W->F 3D): Position3D.position: shape must be 3",
        ),
        (
            {"provider": "db", "edges": [VALID_6D, VALID_6D | {"translation": [1, 0, 0]}]},
            "edges[1]: a second edge named 'C_HT'",
        ),
    ],
)
def test_mistakes_name_the_file_the_entry_and_the_field(tmp_path, document, message):
    path = tmp_path / "calib.yaml"
    path.write_text(yaml.safe_dump(document), encoding="utf-8")
    with pytest.raises(StaticEdgesError, match=re.escape(f"{path}: {message}")):
        read_static_edges(path, T0)


def test_a_quaternion_typed_with_four_decimals_is_normalised():
    typed = [0.7071, 0.0, 0.0, 0.7071]  # norm 0.99999040: beyond the wire's 1e-6
    history = [{"rotation": typed, "translation": [0, 0, 0]}]
    entry = VALID_6D | {"rotation": typed, "history": history}
    _, (edge,) = parse_static_edges({"provider": "db", "edges": [entry]}, T0)
    assert edge.value.rotation == pytest.approx(np.array(typed) / np.linalg.norm(typed))
    assert abs(np.linalg.norm(edge.value.rotation) - 1.0) < 1e-15


def test_unreadable_files(tmp_path):
    with pytest.raises(StaticEdgesError, match=r"missing\.yaml: cannot read"):
        read_static_edges(tmp_path / "missing.yaml", T0)
    broken = tmp_path / "broken.yaml"
    broken.write_text("edges: [", encoding="utf-8")
    with pytest.raises(StaticEdgesError, match=r"broken\.yaml: not valid YAML"):
        read_static_edges(broken, T0)


def test_values_the_format_cannot_hold_are_refused():
    edge = StaticEdge(static_announcement("C", "IP", "3x4"), Position2D(T0, [1, 2]))
    with pytest.raises(ValueError, match="a Position2D cannot be stored as a 3x4 static edge"):
        format_static_edges("db", [edge])


def test_writing_flushes_fsyncs_then_renames_and_leaves_no_temporary(tmp_path, monkeypatch):
    path = tmp_path / "calib.yaml"
    path.write_text("old\n", encoding="utf-8")
    calls: list[tuple[str, object]] = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(descriptor: int) -> None:
        calls.append(("fsync", os.path.isdir(f"/proc/self/fd/{descriptor}")))
        real_fsync(descriptor)

    def replace(source, target) -> None:
        calls.append(("replace", (os.path.dirname(source), os.fspath(target))))
        assert path.read_text(encoding="utf-8") == "old\n"  # untouched until the rename
        real_replace(source, target)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    write_static_edges(path, "db", scenario_edges())
    # the file's data is on disk before the rename, the rename is on disk after it
    assert calls == [
        ("fsync", False),
        ("replace", (str(tmp_path), str(path))),
        ("fsync", True),
    ]
    assert read_static_edges(path, T0)[0] == "db"
    assert os.listdir(tmp_path) == ["calib.yaml"]


def test_a_failed_write_keeps_the_old_file(tmp_path, monkeypatch):
    path = tmp_path / "calib.yaml"
    path.write_text("old\n", encoding="utf-8")

    def disk_full(descriptor: int) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", disk_full)
    with pytest.raises(OSError, match="No space left"):
        write_static_edges(path, "db", scenario_edges())
    assert path.read_text(encoding="utf-8") == "old\n"
    assert os.listdir(tmp_path) == ["calib.yaml"]
    with pytest.raises(FileNotFoundError):
        write_static_edges(tmp_path / "no" / "calib.yaml", "db", scenario_edges())


def test_sim_database_dumps_and_reads_the_file(tmp_path, capsys):
    from ubitrack_agent.cli import build_parser

    path = tmp_path / "calib.yaml"
    args = build_parser().parse_args(["sim", "database", "--dump", str(path)])
    assert args.func(args) == 0
    provider, edges = read_static_edges(path, T0)
    assert provider == SCENARIO.database_provider
    assert [e.announcement for e in edges] == [e.announcement for e in scenario_edges()[:-1]]
    copy = tmp_path / "copy.yaml"
    args = build_parser().parse_args(["sim", "database", "--edges", str(path), "--dump", str(copy)])
    assert args.func(args) == 0
    assert copy.read_text(encoding="utf-8") == path.read_text(encoding="utf-8")
    path.write_text("provider: db\nedges: [{from: C, to: HT, type: 9D}]\n", encoding="utf-8")
    args = build_parser().parse_args(["sim", "database", "--edges", str(path)])
    assert args.func(args) == 2
    assert f"{path}: edges[0].type: must be one of" in capsys.readouterr().err
