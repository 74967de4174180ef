"""The demo's three phases against their steady state (issue 29): ``ubitrack demo`` run N times
in a row, each phase's RMS error beside its steady state's, and whether within 20 %.

Run: ``python -m bench.demo_phases_bench [--runs N] [--phase-seconds S] [--checkout
LABEL=UBITRACK ...]`` (defaults: 10 runs of 5 s phases of this checkout's ``ubitrack``, label
``branch``; about a minute a run on an idle machine). Each run is ``nice -n 10 ubitrack demo
--json`` on a network of its own (a free loopback port, its own domain) with a fresh simulator
seed. With several ``--checkout``s (e.g. ``--checkout main=<a worktree of main>/.venv/bin/ubitrack
--checkout branch=.venv/bin/ubitrack``) their runs alternate, so that each sees the same load:
figures side by side, before and after a change. A demo that fails (it did once when the
machine's load average reached 25: its workers did not start within its minute) is recorded
with its error and the runs go on; the figures are over the runs that ended. Prints a table per
label and writes ``bench/results/demo_phases.json``.

Figures per run and phase, from the demo's JSON lines (the simulator's truth serves only the
errors; the demo's docstring says where each phase begins):

* the phase's RMS translation and rotation error (its ``summary`` line);
* its steady state and worst second **from its once-a-second ``report`` lines**, the same way
  for every checkout: the RMS over the lines from the third on (each line's RMS weighted by its
  samples; :data:`SETTLED_LINES`), and the largest line RMS. The demo's own figures, where it
  prints them (``steady_error_*``, ``worst_second_*``, ``*_within_steady``: from the phase's
  first second on, and a 1 s window sliding over the samples), are kept too, and counted in
  the table's last column;
* ``within``: the phase's RMS at most 1.2 times its steady state's, translation and rotation
  each (the issue's "Done when");
* the mean NEES of the phase's samples and of its steady state, where the demo prints them
  (``nees_mean``, ``steady_nees_mean``; since 2026-11-28): each run calibrates ``C -> HT``
  anew, so its runs are independent batches, and the steady state's mean over the runs is
  judged by their t interval (:func:`bench.synthetic.nees_over_batches`: consistent when 6 is
  inside). The samples of one run share its calibration's error, so one run's mean NEES alone
  says little.

The bench runs processes and reads their output: O(runs) demos, O(samples) arithmetic.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.report import write_results
from bench.synthetic import nees_over_batches

RESULTS = Path(__file__).parent / "results" / "demo_phases.json"
PHASES = ("fused", "camera only", "fused again")
TOLERANCE = 0.2
"""A phase's RMS error is within its steady state's when at most (1 + this) times it."""
UNITS = ("mm", "deg")
SETTLED_LINES = 2
"""The report lines of a phase left out of its steady state here: two seconds, since a phase
of a checkout before issue 29 began before the tracker's processes started (1.2-1.5 s of
camera-only samples in "fused again")."""
RUN_TIMEOUT_S = 300.0
"""The longest one demo may take (calibration included)."""


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def run_demo(ubitrack: str, phase_seconds: float) -> list[dict[str, Any]]:
    """One ``ubitrack demo --json`` on its own network: its JSON lines (a failed run raises)."""
    port = free_port()
    command = [
        *("nice", "-n", "10", ubitrack, "demo", "--json"),
        *("--phase-seconds", str(phase_seconds)),
        *("--listen", f"tcp/127.0.0.1:{port}", "--domain", f"demophases{port}"),
    ]
    demo = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    try:
        out, err = demo.communicate(timeout=RUN_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        os.killpg(demo.pid, signal.SIGTERM)  # the demo and the processes it started
        demo.communicate()
        raise RuntimeError(f"{' '.join(command)} did not end in {RUN_TIMEOUT_S:.0f} s") from None
    if demo.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} exited {demo.returncode}: {err[-2000:]}")
    return [json.loads(line) for line in out.splitlines() if line.startswith("{")]


def from_reports(reports: list[dict[str, Any]], unit: str) -> tuple[float | None, float | None]:
    """A phase's steady-state RMS (its report lines from the :data:`SETTLED_LINES`-th on,
    each weighted by its samples) and worst second (the largest line RMS), from its
    once-a-second lines."""
    later = [r for r in reports[SETTLED_LINES:] if r["samples"] and r[f"error_{unit}_rms"]]
    steady = (
        float(
            np.sqrt(
                sum(r["samples"] * r[f"error_{unit}_rms"] ** 2 for r in later)
                / sum(r["samples"] for r in later)
            )
        )
        if later
        else None
    )
    values = [r[f"error_{unit}_rms"] for r in reports if r[f"error_{unit}_rms"] is not None]
    return steady, (max(values) if values else None)


def judge_run(lines: list[dict[str, Any]]) -> dict[str, Any]:
    """Each phase's figures of one run (module docstring), and its report lines (samples, mm,
    degrees), to judge again otherwise."""
    summaries = {line["phase"]: line for line in lines if line["event"] == "summary"}
    seed = next((line["seed"] for line in lines if line["event"] == "started"), None)
    phases = {}
    for phase in PHASES:
        summary = summaries[phase]
        reports = [line for line in lines if line["event"] == "report" and line["phase"] == phase]
        figures: dict[str, Any] = {
            "samples": summary["samples"],
            "reconfiguration_ms": summary["reconfiguration_ms"],
            "reports": [[r["samples"], r["error_mm_rms"], r["error_deg_rms"]] for r in reports],
            "nees_mean": summary.get("nees_mean"),
            "steady_nees_mean": summary.get("steady_nees_mean"),
        }
        for unit in UNITS:
            whole = summary[f"error_{unit}_rms"]
            steady, worst = from_reports(reports, unit)
            figures[unit] = {
                "rms": whole,
                "steady_rms": steady,
                "worst_second_rms": worst,
                "ratio": whole / steady if whole is not None and steady else None,
                "within": bool(whole is not None and steady and whole <= (1 + TOLERANCE) * steady),
                "demo_steady_rms": summary.get(f"steady_error_{unit}_rms"),
                "demo_worst_second_rms": summary.get(f"worst_second_{unit}_rms"),
                "demo_within": summary.get(f"{unit}_within_steady"),
            }
        phases[phase] = figures
    return {"seed": seed, "phases": phases}


def summarise(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Per phase and unit over the runs: medians of RMS, steady RMS, ratio and worst second,
    the largest ratio, and in how many runs the phase was within; and in how many runs every
    phase was, in both units."""
    table: dict[str, Any] = {}
    for phase in PHASES:
        table[phase] = {}
        for unit in UNITS:
            figures = [run["phases"][phase][unit] for run in runs]

            def median(name: str, figures: list[dict[str, Any]] = figures) -> float | None:
                values = [f[name] for f in figures if f[name] is not None]
                return float(np.median(values)) if values else None

            table[phase][unit] = {
                "rms_median": median("rms"),
                "steady_rms_median": median("steady_rms"),
                "ratio_median": median("ratio"),
                "ratio_max": max((f["ratio"] for f in figures if f["ratio"]), default=None),
                "worst_second_median": median("worst_second_rms"),
                "runs_within": sum(f["within"] for f in figures),
                "runs_demo_within": sum(f["demo_within"] is True for f in figures),
            }
        table[phase]["nees_over_runs"] = {
            name: nees_over_batches([run["phases"][phase].get(name) for run in runs])
            for name in ("nees_mean", "steady_nees_mean")
        }
    every = sum(all(run["phases"][p][u]["within"] for p in PHASES for u in UNITS) for run in runs)
    demo_every = sum(
        all(run["phases"][p][u]["demo_within"] is True for p in PHASES for u in UNITS)
        for run in runs
    )
    return {
        "phases": table,
        "runs": len(runs),
        "runs_every_phase_within": every,
        "runs_every_phase_within_by_the_demo": demo_every,
    }


def print_table(label: str, result: dict[str, Any]) -> None:
    summary = result["summary"]
    print(
        f"\n{label}: {summary['runs']} runs, {result['phase_seconds']} s phases, commit "
        f"{result['commit']}; every phase within {TOLERANCE:.0%} (mm and deg): "
        f"{summary['runs_every_phase_within']} of {summary['runs']}, by the demo's own figures "
        f"{summary['runs_every_phase_within_by_the_demo']} ({summary['failed']} failed to start)"
    )
    print(
        f"{'phase':12s} {'unit':4s} {'RMS':>8s} {'steady':>8s} {'ratio':>6s} {'max':>6s} "
        f"{'worst s':>8s} {'within':>7s} {'demo':>6s}  (medians over runs; max: the largest ratio; "
        "demo: within by the demo's figures)"
    )
    if not summary["runs"]:
        return
    for phase, units in summary["phases"].items():
        for unit in UNITS:
            f = units[unit]
            digits = 3 if unit == "mm" else 4
            print(
                f"{phase:12s} {unit:4s} {f['rms_median']:8.{digits}f} "
                f"{f['steady_rms_median']:8.{digits}f} {f['ratio_median']:6.2f} "
                f"{f['ratio_max']:6.2f} {f['worst_second_median']:8.{digits}f} "
                f"{f['runs_within']:4d}/{summary['runs']} "
                f"{f['runs_demo_within']:3d}/{summary['runs']}"
            )
    print("mean NEES over runs (95 % interval; 6 if the covariance is honest): phase, steady state")
    for phase, units in summary["phases"].items():
        texts = [
            "-"
            if batches is None
            else "{:.2f} ({:.2f}-{:.2f})".format(batches["mean"], *batches["interval_95"])
            for batches in units["nees_over_runs"].values()
        ]
        print(f"{phase:12s} {texts[0]:>20s} {texts[1]:>20s}")


def ratio_text(ratio: float | None) -> str:
    """A phase's RMS over its steady state's, or ``-`` where a phase too short under load had
    no steady state (fewer report lines than :data:`SETTLED_LINES` and one)."""
    return "-" if ratio is None else f"{ratio:.2f}"


def commit_of(ubitrack: str) -> str | None:
    """The git commit of the checkout whose ``ubitrack`` runs (its venv's parent folder)."""
    checkout = Path(ubitrack).resolve().parent.parent.parent
    done = subprocess.run(
        ["git", "-C", str(checkout), "rev-parse", "--short", "HEAD"],
        capture_output=True,
        text=True,
    )
    return done.stdout.strip() or None


def checkout(text: str) -> tuple[str, str]:
    label, _, ubitrack = text.partition("=")
    if not label or not ubitrack:
        raise argparse.ArgumentTypeError(f"{text!r} is not LABEL=UBITRACK")
    return label, ubitrack


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=10, help="demos in a row (default: 10)")
    parser.add_argument("--phase-seconds", type=float, default=5.0, help="(default: 5)")
    parser.add_argument(
        "--checkout",
        type=checkout,
        action="append",
        metavar="LABEL=UBITRACK",
        help="a ubitrack to run, named; repeatable, the runs alternate (default: "
        "branch=<this Python's venv>/bin/ubitrack)",
    )
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    checkouts = dict(args.checkout or [("branch", str(Path(sys.executable).parent / "ubitrack"))])
    started = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
    commits = {label: commit_of(ubitrack) for label, ubitrack in checkouts.items()}
    runs: dict[str, list[dict[str, Any]]] = {label: [] for label in checkouts}
    failed: dict[str, list[str]] = {label: [] for label in checkouts}
    for index in range(args.runs):
        for label, ubitrack in checkouts.items():
            try:
                run = judge_run(run_demo(ubitrack, args.phase_seconds))
            except RuntimeError as exc:
                failed[label].append(str(exc)[-600:])
                print(f"{label} run {index + 1}/{args.runs} failed: {str(exc)[-300:]}", flush=True)
                continue
            runs[label].append(run)
            ratios = "  ".join(
                f"{p}: " + "/".join(ratio_text(run["phases"][p][unit]["ratio"]) for unit in UNITS)
                for p in PHASES
            )
            print(
                f"{label} run {index + 1}/{args.runs} (seed {run['seed']}) RMS/steady mm/deg  "
                f"{ratios}",
                flush=True,
            )
    ended = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
    labels = {
        label: {
            "commit": commits[label],
            "phase_seconds": args.phase_seconds,
            "started": started,
            "ended": ended,
            "load_average_end": os.getloadavg(),
            "machine": {"python": platform.python_version(), "cpus": os.cpu_count()},
            "summary": summarise(runs[label]) | {"failed": len(failed[label])},
            "runs": runs[label],
            "failed": failed[label],
        }
        for label in checkouts
    }
    write_results(args.output, {"labels": labels})
    for label, kept in labels.items():
        print_table(label, kept)


if __name__ == "__main__":
    main()
