"""Instructions one plan executes, counted by Valgrind's callgrind: a measure of the planner's
cost that a shared, noisy machine does not blur (issue [scale]; ``docs/performance.md``,
"Planner, session 21").

Run as ``python -m bench.plan_instructions [ROW ...]`` (rows: ``k7``, a room with seven
redundant trackers, camera -> marker; ``h2h``, head -> head across two rooms with four bodies
seen by two redundant trackers; ``unalike``, the same with the rooms equipped differently;
default those three; ``k50``, ``k200``, ``k500``: the room with 50, 200 and 500 trackers, for
the growth in K, up to a quarter of an hour). For each row it runs, at once, two processes
under ``valgrind --tool=callgrind``, one planning once and one three times (``python -m
bench.plan_instructions --plan ROW N``), and prints half the difference of their instruction
counts: the cost of one plan without the interpreter's start-up and the imports.
``PYTHONHASHSEED`` is fixed (0) so two
checkouts are compared on the same hash order; run with ``PYTHONPATH=<checkout>`` to count
another checkout's planner. Needs ``valgrind`` (Debian package ``valgrind``); writes
``bench/results/plan_instructions.json`` (``--output``). A few minutes per row.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bench import building_bench
from bench.building import build
from ubitrack_agent.graph.planner import plan
from ubitrack_agent.graph.templates import load_templates

ROWS: dict[str, Callable[[], Any]] = {
    "k7": lambda: building_bench.in_room(7),
    "h2h": lambda: building_bench.head_to_head(4, 2),
    "unalike": lambda: building_bench.head_to_head(4, 2, alike=False),
    "k50": lambda: building_bench.in_room(50),
    "k200": lambda: building_bench.in_room(200),
    "k500": lambda: building_bench.in_room(500),
}
DEFAULT_ROWS = ("k7", "h2h", "unalike")
RESULTS = Path(__file__).resolve().parent / "results" / "plan_instructions.json"


def plan_times(row: str, times: int) -> None:
    """Build ``row``'s SRG and plan its query ``times`` times (what callgrind counts)."""
    case = ROWS[row]()
    srg, templates = build(case.shape), load_templates()
    for _ in range(times):
        solutions = plan(srg, templates, case.query)
    print(row, len(solutions), solutions[0].cost, file=sys.stderr)


def instructions(row: str, scratch: Path) -> int:
    """Instructions of one plan of ``row``: (three plans - one plan) / 2, both counted at
    once."""
    env = {**os.environ, "PYTHONHASHSEED": "0"}
    runs = {
        times: subprocess.Popen(
            [
                "valgrind",
                "--tool=callgrind",
                f"--callgrind-out-file={scratch / f'{row}.{times}'}",
                sys.executable,
                "-m",
                "bench.plan_instructions",
                "--plan",
                row,
                str(times),
            ],
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        for times in (1, 3)
    }
    counts = {}
    for times, process in runs.items():
        if process.wait() != 0:
            raise RuntimeError(f"callgrind of {row} x {times} failed")
        text = (scratch / f"{row}.{times}").read_text()
        counts[times] = int(re.search(r"^(?:summary|totals): (\d+)", text, re.M).group(1))
    return (counts[3] - counts[1]) // 2


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rows", nargs="*", default=list(DEFAULT_ROWS), help=", ".join(ROWS))
    parser.add_argument("--plan", nargs=2, metavar=("ROW", "N"), help=argparse.SUPPRESS)
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    if args.plan:
        plan_times(args.plan[0], int(args.plan[1]))
        return 0
    if unknown := set(args.rows) - set(ROWS):
        parser.error(f"unknown rows {sorted(unknown)}; known: {', '.join(ROWS)}")
    if shutil.which("valgrind") is None:
        print("plan_instructions: needs valgrind (apt-get install valgrind)", file=sys.stderr)
        return 2
    results = {}
    with tempfile.TemporaryDirectory() as scratch:
        for row in args.rows:
            results[row] = instructions(row, Path(scratch))
            print(f"{row}: {results[row] / 1e6:.0f} M instructions per plan", flush=True)
    args.output.parent.mkdir(exist_ok=True)
    args.output.write_text(
        json.dumps(
            {
                "command": "python -m bench.plan_instructions " + " ".join(args.rows),
                "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                "instructions_per_plan": results,
            },
            indent=2,
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
