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
another checkout's planner. With ``--caches`` callgrind also simulates the processor's caches
(``--cache-sim=yes``: a first-level data cache and a last-level cache of the host's sizes) and
the misses of one plan are printed beside its instructions, the same difference: first-level
data misses (``D1mr + D1mw``) and last-level misses (``ILmr + DLmr + DLmw``), what makes a plan
slower than its instructions alone as its working set outgrows the caches (about twice the
time under valgrind). Needs ``valgrind`` (Debian package ``valgrind``); writes
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
    "k1000": lambda: building_bench.in_room(1000),
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


def counts(row: str, scratch: Path, caches: bool = False) -> dict[str, int]:
    """Callgrind's events of one plan of ``row`` (``Ir``, instructions, and with ``caches`` the
    simulated misses): (three plans - one plan) / 2, both counted at once."""
    env = {**os.environ, "PYTHONHASHSEED": "0"}
    runs = {
        times: subprocess.Popen(
            [
                "valgrind",
                "--tool=callgrind",
                *(["--cache-sim=yes"] if caches else []),
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
    totals = {}
    for times, process in runs.items():
        if process.wait() != 0:
            raise RuntimeError(f"callgrind of {row} x {times} failed")
        text = (scratch / f"{row}.{times}").read_text()
        events = re.search(r"^events: (.+)$", text, re.M).group(1).split()
        values = re.search(r"^(?:summary|totals): (.+)$", text, re.M).group(1).split()
        totals[times] = dict(zip(events, map(int, values), strict=False))
    return {event: (totals[3][event] - totals[1][event]) // 2 for event in totals[1]}


def misses(events: dict[str, int]) -> dict[str, int]:
    """First-level data misses and last-level misses of callgrind's cache events."""
    return {
        "d1_misses": events["D1mr"] + events["D1mw"],
        "ll_misses": events["ILmr"] + events["DLmr"] + events["DLmw"],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rows", nargs="*", default=list(DEFAULT_ROWS), help=", ".join(ROWS))
    parser.add_argument("--plan", nargs=2, metavar=("ROW", "N"), help=argparse.SUPPRESS)
    parser.add_argument("--output", type=Path, default=RESULTS)
    parser.add_argument(
        "--caches", action="store_true", help="also count simulated cache misses (slower)"
    )
    args = parser.parse_args(argv)
    if args.plan:
        plan_times(args.plan[0], int(args.plan[1]))
        return 0
    if unknown := set(args.rows) - set(ROWS):
        parser.error(f"unknown rows {sorted(unknown)}; known: {', '.join(ROWS)}")
    if shutil.which("valgrind") is None:
        print("plan_instructions: needs valgrind (apt-get install valgrind)", file=sys.stderr)
        return 2
    results, caches = {}, {}
    with tempfile.TemporaryDirectory() as scratch:
        for row in args.rows:
            events = counts(row, Path(scratch), args.caches)
            results[row] = events["Ir"]
            line = f"{row}: {results[row] / 1e6:.0f} M instructions per plan"
            if args.caches:
                caches[row] = misses(events)
                line += (
                    f", {caches[row]['d1_misses'] / 1e6:.1f} M first-level data misses, "
                    f"{caches[row]['ll_misses'] / 1e6:.2f} M last-level misses"
                )
            print(line, flush=True)
    args.output.parent.mkdir(exist_ok=True)
    args.output.write_text(
        json.dumps(
            {
                "command": "python -m bench.plan_instructions "
                + " ".join(args.rows)
                + (" --caches" if args.caches else ""),
                "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                "instructions_per_plan": results,
                **({"misses_per_plan": caches} if args.caches else {}),
            },
            indent=2,
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
