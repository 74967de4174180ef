"""How soon ``ubitrack subscribe`` and ``ubitrack calibrate`` say what the agent answered (issue
31, item 1), measured from outside: the wall time from starting the command to its exit (or to
a line it prints), as a user waits for it.

Run: ``python -m bench.answer_latency_bench [--runs 5] [--label after] [--cap 15]``.
Everything on loopback with real zenoh and real processes: an agent (with its host manager), the
simulated calibration database (``ubitrack sim database``: frames C, IP, HT, WT, A, F1..F5)
and a noise-free tracker (``ubitrack_agent.sim_trackers.exact_tracker``: ART->WT, ART->HT).
Cases, each ``--runs`` times, a fresh command process each time (so every figure includes the
interpreter's start and the imports, ``imports``):

* ``imports``: ``python -c "import zenoh, ubitrack_agent.io.application"``, the floor under
  every other figure;
* ``subscribe_unsolved`` / ``calibrate_unsolved``: ``subscribe C NOPE`` / ``calibrate C NOPE``
  with the agent running: to the exit with the agent's reason;
* ``subscribe_no_agent`` / ``calibrate_no_agent``: the same commands connecting to a port
  nobody listens on: to the exit saying there is no agent;
* ``subscribe_starting``: ``subscribe WT HT --count 1``, whose flow (an inversion and a
  concatenation) is started for it: to the progress line (``planned: ...``), to the first
  sample, and to the exit. Between runs the bench waits until the agent has stopped the flow,
  so every run starts it anew.

A command still running at ``--cap`` seconds is killed and its figure recorded as the cap
(``capped`` counts them): before issue 31 the unsolved and no-agent cases ran to the
commands' time-outs (10 s, and 300 s for ``calibrate``). ``median_beyond_imports_s`` is a
case's median less that of ``imports``: what waiting for the answer adds on a loaded machine,
where the interpreter's start varies most. Medians in seconds are printed and
written to ``bench/results/answer_latency.json`` under ``--label`` (other labels in the file are
kept, so runs before and after a change sit side by side).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import selectors
import statistics
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from tests.integration.conftest import end_groups
from tests.integration.test_agent import Setup, opened
from tests.integration.zenoh_helpers import free_port, member_flags, wait_until

RESULTS = Path(__file__).with_name("results") / "answer_latency.json"
CLI = [sys.executable, "-m", "ubitrack_agent.cli"]


def timed_command(command: list[str], cap: float, marks: dict[str, str]) -> dict[str, Any]:
    """Run ``command`` to its end (killed at ``cap`` s): its wall time, exit code, the time of
    the first output line containing each of ``marks`` (name -> text) and its last stderr
    line. O(lines printed)."""
    start = time.monotonic()
    process = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    seen: dict[str, float] = {}
    errors: list[str] = []
    with selectors.DefaultSelector() as selector:
        for stream in (process.stdout, process.stderr):
            selector.register(stream, selectors.EVENT_READ)
        open_streams = 2
        while open_streams and time.monotonic() - start < cap:
            for key, _ in selector.select(timeout=0.05):
                line = key.fileobj.readline()
                if not line:
                    selector.unregister(key.fileobj)
                    open_streams -= 1
                    continue
                if key.fileobj is process.stderr and line.strip():
                    errors.append(line.strip())
                for name, text in marks.items():
                    if name not in seen and text in line:
                        seen[name] = time.monotonic() - start
    capped = process.poll() is None and open_streams > 0
    if capped:
        end_groups([process])
    code = process.wait()
    return {
        "wall_s": min(time.monotonic() - start, cap) if not capped else cap,
        "code": code,
        "capped": capped,
        "marks": seen,
        "last_error": errors[-1] if errors else "",
    }


def summary(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Medians of ``runs`` (wall time and each mark), exit codes, capped runs, a message."""
    marks = sorted({name for run in runs for name in run["marks"]})
    return {
        "median_s": round(statistics.median(r["wall_s"] for r in runs), 3),
        "runs_s": [round(r["wall_s"], 3) for r in runs],
        **{
            f"median_{name}_s": round(
                statistics.median(r["marks"][name] for r in runs if name in r["marks"]), 3
            )
            for name in marks
        },
        **{f"{name}_seen": sum(name in r["marks"] for r in runs) for name in marks},
        "exit_codes": [r["code"] for r in runs],
        "capped": sum(r["capped"] for r in runs),
        "message": runs[-1]["last_error"][:300],
    }


def system(processes: list[subprocess.Popen]) -> Iterator[Setup]:
    """The agent, the database and a tracker on a fresh port and domain, all announced."""
    for setup in opened(processes):
        setup.start_agent()
        setup.start("-m", "ubitrack_agent.cli", "sim", "database", "--quiet")
        setup.tracker("art", "ART", 30.0, 2.0)
        wait_until(lambda s=setup: announced(s), timeout=30)
        yield setup


def announced(setup: Setup) -> bool:
    """Whether the agent has both providers of :func:`system`."""
    return {"art", "database"} <= set((setup.status() or {}).get("providers", {}))


def idle(setup: Setup) -> bool:
    """Whether the agent runs no component (the previous run's flow has stopped)."""
    status = setup.status()
    return status is not None and not status["components"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.answer_latency_bench")
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--cap", type=float, default=15.0, help="kill a command after this")
    parser.add_argument("--label", default="after", help="key of these figures in the file")
    args = parser.parse_args(argv)
    nobody = ["--connect", f"tcp/127.0.0.1:{free_port()}", "--domain", "nobody"]
    imports = [sys.executable, "-c", "import zenoh, ubitrack_agent.io.application"]
    results: dict[str, list[dict[str, Any]]] = {}

    def measure(name: str, command: list[str], marks: dict[str, str] | None = None) -> None:
        run = timed_command(command, args.cap, marks or {})
        results.setdefault(name, []).append(run)
        print(f"{name}: {run['wall_s']:.2f} s, exit {run['code']}, {run['marks']}", flush=True)

    processes: list[subprocess.Popen] = []
    try:
        for setup in system(processes):
            member = member_flags(setup.port, setup.domain)
            for _ in range(args.runs):
                measure("imports", imports)
                measure("subscribe_unsolved", [*CLI, "subscribe", "C", "NOPE", *member])
                measure("calibrate_unsolved", [*CLI, "calibrate", "C", "NOPE", *member])
                measure("subscribe_no_agent", [*CLI, "subscribe", "C", "A", *nobody])
                measure("calibrate_no_agent", [*CLI, "calibrate", "C", "A", *nobody])
                wait_until(lambda s=setup: idle(s), timeout=30)
                measure(
                    "subscribe_starting",
                    [*CLI, "subscribe", "WT", "HT", "--count", "1", *member],
                    {"progress": "planned:", "first_sample": '"timestamp_ns"'},
                )
    finally:
        end_groups(processes)
    figures = {name: summary(runs) for name, runs in results.items()}
    floor = figures["imports"]["median_s"]
    for figure in figures.values():  # what the command spends beyond starting Python
        figure["median_beyond_imports_s"] = round(figure["median_s"] - floor, 3)
    document = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    document[args.label] = {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "machine": f"{platform.machine()}, {os.cpu_count()} CPUs, load {os.getloadavg()[0]:.1f}",
        "runs": args.runs,
        "cap_s": args.cap,
        "cases": figures,
    }
    RESULTS.write_text(json.dumps(document, indent=2) + "\n")
    for name, figure in figures.items():
        marks = {k: v for k, v in figure.items() if k.startswith("median_") and k != "median_s"}
        print(f"{name:22s} median {figure['median_s']:7.3f} s  exit {figure['exit_codes']} {marks}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
