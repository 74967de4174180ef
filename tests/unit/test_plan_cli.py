"""``ubitrack plan``: the offline design tool (section 5.2.2)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from ubitrack_agent.cli import main
from ubitrack_agent.sim_trackers.scenario import DEFAULT_SCENARIO as SCENARIO

ROOT = Path(__file__).resolve().parents[2]

TRACKING = str(ROOT / "examples" / "paper_tracking.yaml")
CALIBRATION = str(ROOT / "examples" / "paper_calibration.yaml")
POINTER = str(ROOT / "examples" / "pointer_tip.yaml")


def run_json(capsys, *args):
    status = main(["plan", *args, "--json"])
    out = capsys.readouterr().out
    return status, json.loads(out)


def test_json_output_follows_the_issue_schema(capsys):
    status, document = run_json(capsys, TRACKING, "--from", "C", "--to", "A", "--type", "6D")
    assert status == 0
    assert document["query"] == {"from": "C", "to": "A", "type": "6D", "static": False}
    (best,) = document["solutions"]  # without --all only the best
    assert set(best) == {"cost", "static", "measured", "steps"}
    assert isinstance(best["cost"], float) and best["static"] is False
    assert ["C", "HT", "6D", "database"] in best["measured"]  # with the providers
    assert ["ART", "HT", "6D", "ART"] in best["measured"] and len(best["measured"]) == 15
    patterns = [s["pattern"] for s in best["steps"]]
    assert sorted(patterns) == sorted(
        ["PoseEstimation2D3D", "Inversion"] + ["Concatenation"] * 3 + ["MultiTrackerFusion"]
    )
    for step in best["steps"]:
        assert set(step) == {"pattern", "expansion", "inputs", "outputs"}
        assert step["expansion"] in ("none", "space", "time")
        assert all(len(edge) == 3 for edge in step["inputs"] + step["outputs"])
    assert best["steps"][-1]["outputs"] == [["C", "A", "6D"]]


def test_all_lists_the_calibration_alternatives_best_first(capsys):
    args = (CALIBRATION, "--from", "C", "--to", "HT", "--type", "6D", "--static", "--all")
    status, document = run_json(capsys, *args)
    assert status == 0
    solutions = document["solutions"]
    assert len(solutions) >= 3
    assert [s["cost"] for s in solutions] == sorted(s["cost"] for s in solutions)
    assert all(s["static"] for s in solutions)
    patterns = [{step["pattern"] for step in s["steps"]} for s in solutions]
    assert any("HandEyeCalibration" in p for p in patterns)
    assert sum("Averaging" in p for p in patterns) >= 2


def test_text_output(capsys):
    assert main(["plan", TRACKING, "--from", "C", "--to", "A", "--type", "6D"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("6D C->A: 4 solution(s), the best shown (--all for the other 3)\n")
    assert out.count("\nsolution ") == 1
    assert main(["plan", TRACKING, "--from", "C", "--to", "A", "--type", "6D", "--all"]) == 0
    every = capsys.readouterr().out
    assert every.startswith("6D C->A: 4 solution(s)\n") and every.count("\nsolution ") == 4
    assert "MultiTrackerFusion (space)" in out


def test_no_solution_exits_2_and_names_the_frames(capsys, tmp_path):
    setup = tmp_path / "split.yaml"
    setup.write_text("edges:\n  - {from: A, to: B, type: 6D}\n  - {from: C, to: D, type: 6D}\n")
    status = main(["plan", str(setup), "--from", "A", "--to", "D", "--type", "6D", "--json"])
    captured = capsys.readouterr()
    assert status == 2
    assert captured.out == ""
    assert "A and D are not connected" in captured.err


def test_bad_setup_file_exits_1_with_the_reason(capsys, tmp_path):
    setup = tmp_path / "bad.yaml"
    setup.write_text("edges:\n  - {from: A, to: B, type: 6D, colour: red}\n")
    status = main(["plan", str(setup), "--from", "A", "--to", "B", "--type", "6D"])
    err = capsys.readouterr().err
    assert status == 1
    assert "bad.yaml: edges[0]: unknown field(s) ['colour']" in err


def test_dot_file_shows_the_chosen_data_flow(capsys, tmp_path, monkeypatch):
    monkeypatch.setattr("shutil.which", lambda name: None)  # no graphviz: DOT only
    dot = tmp_path / "plan.dot"
    status = main(["plan", TRACKING, "--from", "C", "--to", "A", "--type", "6D", "--dot", str(dot)])
    assert status == 0
    text = dot.read_text()
    assert text.startswith('digraph "C->A"')
    assert text.count("style=dashed") == 6  # one inferred edge per step of figure 6
    assert '"ART" -> "HT" [label="6D", style=bold' in text
    assert "install graphviz" in capsys.readouterr().err


def test_hosts_show_where_each_step_would_run(capsys, tmp_path, monkeypatch):
    monkeypatch.setattr("shutil.which", lambda name: None)
    query = [TRACKING, "--from", "C", "--to", "A", "--type", "6D"]
    status, document = run_json(capsys, *query, "--host", "room", "--host", "hmd")
    assert status == 0
    (best,) = document["solutions"]
    where = {
        (step["pattern"], tuple(step["outputs"][0])): host
        for step, host in zip(best["steps"], best["hosts"], strict=True)
    }
    assert where[("PoseEstimation2D3D", ("C", "WT", "6D"))] == "hmd"  # beside the camera
    assert where[("Inversion", ("HT", "ART", "6D"))] == "room"  # beside the A.R.T.
    # The last hop goes beside the application when that saves a crossing.
    last = ("Concatenation", ("C", "A", "6D"))
    _, beside_hmd = run_json(capsys, *query, "--host", "room", "--host", "hmd", "--app-host", "hmd")
    _, beside_room = run_json(
        capsys, *query, "--host", "room", "--host", "hmd", "--app-host", "room"
    )
    for document, host in ((beside_hmd, "hmd"), (beside_room, "room")):
        steps = document["solutions"][0]
        hosts = dict(
            zip(
                ((s["pattern"], tuple(s["outputs"][0])) for s in steps["steps"]),
                steps["hosts"],
                strict=True,
            )
        )
        assert hosts[last] == host
    dot = tmp_path / "plan.dot"
    assert main(["plan", *query, "--host", "room", "--host", "hmd", "--dot", str(dot)]) == 0
    assert "PoseEstimation2D3D (space) 6D\\non hmd" in dot.read_text()
    # A template's required label no host has: the step has no host.
    templates = tmp_path / "templates"
    templates.mkdir()
    for source in (ROOT / "templates").glob("*.yaml"):
        text = source.read_text()
        if source.name == "pose_estimation_2d3d.yaml":
            text += "host_labels: [gpu]\n"
        (templates / source.name).write_text(text)
    capsys.readouterr()
    assert main(["plan", *query, "--templates", str(templates), "--host", "room"]) == 0
    assert "PoseEstimation2D3D (space)" in (out := capsys.readouterr().out)
    assert "on (no host fits)" in out
    assert main(["plan", *query, "--app-host", "hmd"]) == 1
    assert "--app-host needs --host" in capsys.readouterr().err


def test_help_lists_the_options(capsys):
    with pytest.raises(SystemExit) as info:
        main(["plan", "--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    for option in ("--from", "--to", "--type", "--static", "--all", "--json", "--dot"):
        assert option in out
    assert "FILE [FILE ...]" in out and "static-edges file" in out and "scenario" in out


def test_without_plans_as_if_a_sensor_had_failed(capsys):
    query = (TRACKING, "--from", "C", "--to", "A", "--type", "6D")
    status, document = run_json(capsys, *query, "--without", "ART")
    assert status == 0
    steps = document["solutions"][0]["steps"]
    assert "ART" not in {frame for step in steps for edge in step["inputs"] for frame in edge[:2]}
    assert "MultiTrackerFusion" not in {step["pattern"] for step in steps}
    assert main(["plan", *query, "--without", "NOPE"]) == 1
    assert "--without NOPE: no such provider" in capsys.readouterr().err


def test_a_static_query_to_the_pointer_tip_plans_its_tip_calibration(capsys):
    assert main(["plan", POINTER, "--from", "M", "--to", "Tip", "--type", "3D", "--static"]) == 0
    assert capsys.readouterr().out.splitlines() == [
        "static 3D M->Tip: 1 solution(s)",
        "",
        "solution 1: cost 0.628, static",
        "  1. TipCalibration (time): T->M:6D  =>  M->Tip:3D, T->Tip:3D",
        "  measured: T->M:6D (T)",
    ]
    # T->Tip is the pivot: Tip fixed in T, about which one of the bodies was turned
    status, document = run_json(
        capsys, POINTER, "--from", "T", "--to", "Tip", "--type", "3D", "--static", "--all"
    )
    assert status == 0
    assert [s["steps"] for s in document["solutions"]] == [
        [
            {
                "pattern": "TipCalibration",
                "expansion": "time",
                "inputs": [["T", body, "6D"]],
                "outputs": [[body, "Tip", "3D"], ["T", "Tip", "3D"]],
            }
        ]
        for body in ("M", "R")
    ]


def test_the_calibrated_tip_is_tracked_once_stored_as_a_static_edge(capsys, tmp_path):
    query = ("--from", "T", "--to", "Tip", "--type", "3D")
    assert main(["plan", POINTER, *query]) == 2  # which body's tip: the query does not say
    assert "a calibration introduces a frame only for a static query" in capsys.readouterr().err
    stored = tmp_path / "pointer_calibrated.yaml"
    text = Path(POINTER).read_text(encoding="utf-8")
    stored.write_text(text + "  - {from: M, to: Tip, type: 3D, static: true}\n", encoding="utf-8")
    status, document = run_json(capsys, str(stored), *query)
    assert status == 0
    (step,) = document["solutions"][0]["steps"]
    assert step["pattern"] == "Concatenation"
    assert step["inputs"] == [["T", "M", "6D"], ["M", "Tip", "3D"]]


def test_a_static_edges_file_serves_an_edge_the_setup_lacks(capsys, tmp_path):
    """Offline on the files the live system uses: the tracking setup without C->HT plus the
    calibration store's file holding it."""
    setup = yaml.safe_load(Path(TRACKING).read_text(encoding="utf-8"))
    setup["edges"] = [e for e in setup["edges"] if (e["from"], e["to"]) != ("C", "HT")]
    without = tmp_path / "tracking_without_c_ht.yaml"
    without.write_text(yaml.safe_dump(setup), encoding="utf-8")
    store = tmp_path / "store.yaml"
    c_ht = {"from": "C", "to": "HT", "type": "6D", "rotation": [0.7071, 0, 0, 0.7071]}  # typed
    c_ht |= {"translation": [0.03, -0.06, 0.04], "covariance": (np.eye(6) * 1e-8).tolist()}
    store.write_text(yaml.safe_dump({"provider": "store", "edges": [c_ht]}), encoding="utf-8")
    query = ("--from", "C", "--to", "A", "--type", "6D")
    assert main(["plan", str(without), *query]) == 0
    assert "MultiTrackerFusion" not in capsys.readouterr().out  # the camera alone
    status, document = run_json(capsys, str(without), str(store), *query)
    assert status == 0
    best = document["solutions"][0]
    assert "MultiTrackerFusion" in {step["pattern"] for step in best["steps"]}  # figure 6
    assert ["C", "HT", "6D"] in [edge for step in best["steps"] for edge in step["inputs"]]
    assert [e for e in best["measured"] if e[:2] == ["C", "HT"]] == [["C", "HT", "6D", "store"]]
    assert main(["plan", str(without), str(store), *query, "--without", "store"]) == 0
    assert "C->HT:6D (store)" not in capsys.readouterr().out
    # given beside the full setup, the stored edge replaces the setup's database edge
    assert main(["plan", TRACKING, str(store), "--from", "C", "--to", "HT", "--type", "6D"]) == 0
    captured = capsys.readouterr()
    assert "  measured: C->HT:6D (store)" in captured.out.splitlines()
    assert f"{store}: edges[0] C->HT 6D (provider store) replaces {TRACKING}: edges[2]" in (
        captured.err
    )


def test_a_scenario_plans_as_its_simulators_announce(capsys, tmp_path):
    """The default scenario's database lacks C->HT: the camera alone, until a store has it."""
    query = ("--from", "C", "--to", "A", "--type", "6D")
    status, document = run_json(capsys, str(SCENARIO), *query)
    assert status == 0
    measured = document["solutions"][0]["measured"]
    assert {provider for *_, provider in measured} == {"camera", "database"}
    store = tmp_path / "store.yaml"
    c_ht = {"from": "C", "to": "HT", "type": "6D", "rotation": [0, 0, 0, 1]}
    c_ht |= {"translation": [0.03, -0.06, 0.04], "covariance": (np.eye(6) * 1e-8).tolist()}
    store.write_text(yaml.safe_dump({"provider": "store", "edges": [c_ht]}), encoding="utf-8")
    status, document = run_json(capsys, str(SCENARIO), str(store), *query)
    assert status == 0
    measured = document["solutions"][0]["measured"]
    assert {provider for *_, provider in measured} == {"ART", "camera", "database", "store"}


def test_an_unknown_document_names_the_formats_plan_reads(capsys, tmp_path):
    other = tmp_path / "settings.yaml"
    other.write_text("mode: peer\n", encoding="utf-8")
    assert main(["plan", str(other), "--from", "C", "--to", "A", "--type", "6D"]) == 1
    err = capsys.readouterr().err
    assert f"{other}: not a document ubitrack plan reads; expected a setup file" in err
    assert "static-edges file" in err and "simulator scenario" in err
