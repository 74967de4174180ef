"""Tracking on a live calibration against tracking on the true one, and the calibration's NEES.

Run: ``python -m bench.calibrated_tracking_bench [--runs N] [--phase-seconds S]`` (defaults 5
pairs of 8 s phases, about 15 minutes on 2 vCPUs). Prints a table and writes
``bench/results/calibrated_tracking.json``.

Each pair runs ``ubitrack demo --json`` twice, in alternating order, on the same machine:

* **calibrated**: the default scenario (its database lacks ``C -> HT``): the demo calibrates
  ``C -> HT`` live, stores it, then tracks ``C -> A`` on the stored value;
* **true**: the default scenario with ``C -> HT`` added to its database, which then serves the
  simulator's truth (what the demo did before it calibrated).

Pair ``i`` seeds the simulators with ``SEED_BASE + i``: the two runs of a pair see the same
noise, different pairs independent noise. Reported per run: the seed, the calibration's time,
samples, error against the truth and its NEES (``e^T P^-1 e`` of the left-perturbation error
with the stored covariance ``P``, 6 degrees of freedom: the mean over runs lies in the
chi-square interval printed beside it when the covariance is consistent), and each tracking
phase's RMS error of ``C -> A`` (the ErrorPose the application receives, against the
simulator's truth). Summary: medians, and the ratio of the
calibrated runs' median fused RMS to the true runs' (the issue's bound is 1.5).
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
import time
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from scipy import stats

from bench.synthetic import left_error
from ubitrack_agent.io.static_edges import read_static_edges
from ubitrack_agent.services.algorithms.estimate import PoseEstimate
from ubitrack_agent.sim_trackers.scenario import load_scenario

RESULTS = Path(__file__).parent / "results" / "calibrated_tracking.json"
PHASES = ("fused", "camera only", "fused again")
SEED_BASE = 1000
"""Pair ``i`` runs its simulators with seed ``SEED_BASE + i`` (``ubitrack demo --seed``): with
one seed for all, every run would replay the same noise and the mean NEES would be one draw."""


def scenario_with_true_calibration(directory: Path) -> Path:
    """The default scenario with ``C -> HT`` in its database (served from the truth)."""
    text = (
        resources.files("ubitrack_agent.sim_trackers")
        .joinpath("scenarios/paper_figure1.yaml")
        .read_text()
    )
    document = yaml.safe_load(text)
    document["database"]["edges"].append({"from": "C", "to": "HT", "type": "6D"})
    path = directory / "figure1_true_calibration.yaml"
    path.write_text(yaml.safe_dump(document))
    return path


def run_demo(
    phase_seconds: float, scenario: Path | None, store: Path, seed: int
) -> list[dict[str, Any]]:
    """One ``ubitrack demo --json`` run with simulator seed ``seed``; its JSON lines."""
    command = [sys.executable, "-m", "ubitrack_agent.cli", "demo", "--json", "--seed", str(seed)]
    command += ["--phase-seconds", str(phase_seconds), "--calibration", str(store)]
    if scenario is not None:
        command += ["--scenario", str(scenario)]
    out = subprocess.run(command, capture_output=True, text=True, timeout=600)
    if out.returncode != 0:
        raise RuntimeError(f"demo failed ({out.returncode}): {out.stderr[-2000:]}")
    return [json.loads(line) for line in out.stdout.splitlines() if line.startswith("{")]


def calibration_nees(store: Path) -> float:
    """NEES of the stored ``C -> HT`` against the scenario's truth."""
    _, edges = read_static_edges(store, 0)
    (edge,) = [e for e in edges if e.announcement.name == "C_HT"]
    q, t = load_scenario().world.pose("C", "HT", 0)
    error = left_error(
        PoseEstimate(edge.value.rotation, edge.value.translation, None), PoseEstimate(q, t, None)
    )
    return float(error @ np.linalg.solve(edge.value.covariance, error))


def one_run(kind: str, phase_seconds: float, directory: Path, index: int) -> dict[str, Any]:
    store = directory / f"store-{kind}-{index}.yaml"
    scenario = scenario_with_true_calibration(directory) if kind == "true" else None
    seed = SEED_BASE + index  # both runs of a pair see the same noise, pairs independent noise
    lines = run_demo(phase_seconds, scenario, store, seed)
    (calibration,) = [line for line in lines if line["event"] == "calibration"]
    summaries = {line["phase"]: line for line in lines if line["event"] == "summary"}
    run = {
        "kind": kind,
        "seed": seed,
        "calibration": {
            key: calibration[key]
            for key in ("outcome", "seconds", "samples", "rejected", "error_mm", "error_deg")
        },
        "phases": {
            phase: {key: summaries[phase][key] for key in ("samples", "error_mm_rms")}
            for phase in PHASES
        },
    }
    if kind == "calibrated":
        run["calibration"]["nees"] = calibration_nees(store)
    return run


def summarise(runs: list[dict[str, Any]]) -> dict[str, Any]:
    summary: dict[str, Any] = {}
    for kind in ("true", "calibrated"):
        mine = [run for run in runs if run["kind"] == kind]
        summary[kind] = {
            phase: float(np.median([run["phases"][phase]["error_mm_rms"] for run in mine]))
            for phase in PHASES
        }
    calibrated = [run["calibration"] for run in runs if run["kind"] == "calibrated"]
    nees = [c["nees"] for c in calibrated]
    count = len(nees)
    summary["calibration"] = {
        "converged": sum(c["outcome"] == "converged" for c in calibrated),
        "runs": count,
        "seconds_median": float(np.median([c["seconds"] for c in calibrated])),
        "seconds_max": float(max(c["seconds"] for c in calibrated)),
        "error_mm_max": float(max(c["error_mm"] for c in calibrated)),
        "error_deg_max": float(max(c["error_deg"] for c in calibrated)),
        "nees_mean": float(np.mean(nees)),
        "nees_interval_95": [
            float(stats.chi2.ppf(0.025, 6 * count) / count),
            float(stats.chi2.ppf(0.975, 6 * count) / count),
        ],
    }
    summary["fused_ratio_calibrated_to_true"] = (
        summary["calibrated"]["fused"] / summary["true"]["fused"]
    )
    return summary


def print_summary(runs: list[dict[str, Any]], summary: dict[str, Any]) -> None:
    print("\n| run | C->HT | calibration | fused | camera only | fused again |")
    print("|---|---|---|---|---|---|")
    for index, run in enumerate(runs):
        c = run["calibration"]
        calibration = (
            f"{c['seconds']} s, {c['samples']} samples, {c['error_mm']} mm / {c['error_deg']}°, "
            f"NEES {c['nees']:.1f}"
            if run["kind"] == "calibrated"
            else "served (truth)"
        )
        errors = " | ".join(f"{run['phases'][p]['error_mm_rms']:.2f} mm" for p in PHASES)
        print(f"| {index} | {run['kind']} | {calibration} | {errors} |")
    c = summary["calibration"]
    low, high = c["nees_interval_95"]
    print(
        f"\ncalibration: converged {c['converged']}/{c['runs']}, median {c['seconds_median']:.1f} s"
        f" (max {c['seconds_max']:.1f} s), largest error {c['error_mm_max']:.2f} mm / "
        f"{c['error_deg_max']:.3f}°, mean NEES {c['nees_mean']:.2f} (95 % interval for a "
        f"consistent covariance [{low:.2f}, {high:.2f}])"
    )
    for kind in ("true", "calibrated"):
        medians = ", ".join(f"{p} {summary[kind][p]:.2f} mm" for p in PHASES)
        print(f"median RMS of C->A, C->HT {kind}: {medians}")
    print(f"fused, calibrated / true: {summary['fused_ratio_calibrated_to_true']:.2f}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5, help="pairs of demo runs")
    parser.add_argument("--phase-seconds", type=float, default=8.0)
    args = parser.parse_args(argv)
    runs = []
    with tempfile.TemporaryDirectory() as scratch:
        for index in range(args.runs):
            order = ("true", "calibrated") if index % 2 == 0 else ("calibrated", "true")
            for kind in order:
                runs.append(one_run(kind, args.phase_seconds, Path(scratch), index))
                print(f"run {len(runs)}: {json.dumps(runs[-1])}", flush=True)
    summary = summarise(runs)
    print_summary(runs, summary)
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(
        json.dumps(
            {
                "command": "python -m bench.calibrated_tracking_bench "
                f"--runs {args.runs} --phase-seconds {args.phase_seconds:g}",
                "date": time.strftime("%Y-%m-%d"),
                "machine": {"python": platform.python_version(), "numpy": np.__version__},
                "summary": summary,
                "runs": runs,
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
