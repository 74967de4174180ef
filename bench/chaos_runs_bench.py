"""Seeded chaos runs in a row (issue 28, "Done when": chaos green with containers, 10 runs in
a row, healthy within 10 s of the churn's end): how long after its last fault each run's
system is healthy again.

Each run is the chaos test's (``tests/integration/test_chaos.py``) on a fresh system: an agent
with its host manager (warm pool of 3; a host's components share its containers, one per core),
two noise-free trackers and the applications ``WT->HT`` and ``HT->WT`` (ten components), steady
first (``bench.churn_bench.steady``); then ``--events`` faults of ``chaos_faults.Chaos`` drawn
from ``random.Random(seed)`` for seeds ``--first-seed``, ``--first-seed + 1``, ... (a tracker
killed and started again, a process running components killed: a container, the agent killed
and started again, a query opened and closed at once), one every 1.0-2.5 s. After the last
fault (and its follow-up) the bench asks every ``POLL_S`` whether the system is *healthy*
(``chaos_faults.whole`` with ``pool_settled=False``: the agent serving every relation, each
wanted component alive in exactly one process, nothing unwanted running, every other worker
process a pool member, ready or starting), whether both applications also receive fresh,
correct samples (the last second), and whether the warm pool is full again (the chaos test's
check, ``whole``); up to ``--timeout`` seconds. Run::

    .venv/bin/python -m bench.chaos_runs_bench [--runs 10] [--first-seed 11] [--events 14]

Printed, and written to ``bench/results/chaos_runs.json``: per run the seed, the faults, the
seconds to healthy and to fresh data (or what was still wrong at the timeout), the load.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import statistics
import sys
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from bench.churn_bench import APPLICATIONS, POOL_SIZE, machine, system
from tests.integration.chaos_faults import whole

RESULTS = Path(__file__).with_name("results") / "chaos_runs.json"
POLL_S = 0.25
HEALTHY_WITHIN_S = 10.0
"""The issue's bound on the time to healthy after the churn's end."""


def one_run(seed: int, events: int, timeout: float) -> dict[str, Any]:
    """A fresh system, ``events`` faults from ``seed``, then the time to healthy."""
    with system(POOL_SIZE, seed) as (chaos, apps):
        chaos.rng = random.Random(seed)
        load = os.getloadavg()[0]
        chaos.run(events)
        ended = time.monotonic()
        healthy_s = fresh_s = settled_s = None
        problem = None
        while time.monotonic() - ended < timeout:
            now = time.monotonic() - ended
            if healthy_s is None:
                problem = whole(chaos.setup, chaos.pool_size, pool_settled=False)
                healthy_s = now if problem is None else None
            if healthy_s is not None and fresh_s is None:
                since = time.time() - 1.0
                stale = [str(r) for r in APPLICATIONS if not apps.fresh_since(r, since)]
                fresh_s = now if not stale else None
                problem = f"not fresh: {stale}" if stale else None
            if fresh_s is not None:
                problem = whole(chaos.setup, chaos.pool_size)
                if problem is None:
                    settled_s = now
                    break
            time.sleep(POLL_S)
        return {
            "seed": seed,
            "faults": list(chaos.log),
            "healthy_after_s": None if healthy_s is None else round(healthy_s, 2),
            "fresh_after_s": None if fresh_s is None else round(fresh_s, 2),
            "pool_full_after_s": None if settled_s is None else round(settled_s, 2),
            "problem": problem,
            "load_1min": [round(load, 1), round(os.getloadavg()[0], 1)],
        }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.chaos_runs_bench", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=11)
    parser.add_argument("--events", type=int, default=14, help="faults per run (14)")
    parser.add_argument("--timeout", type=float, default=60.0, help="s after the faults (60)")
    args = parser.parse_args(argv)
    runs = []
    for seed in range(args.first_seed, args.first_seed + args.runs):
        runs.append(one_run(seed, args.events, args.timeout))
        print(json.dumps(runs[-1]), flush=True)
    healthy = [r["healthy_after_s"] for r in runs if r["healthy_after_s"] is not None]
    results = {
        "command": "python -m bench.chaos_runs_bench " + " ".join(argv or sys.argv[1:]),
        "date": datetime.now(UTC).strftime("%Y-%m-%d"),
        "machine": machine(),
        "runs": runs,
        "healthy_within_10_s": sum(s <= HEALTHY_WITHIN_S for s in healthy),
        "healthy_median_s": round(statistics.median(healthy), 2) if healthy else None,
        "healthy_max_s": max(healthy) if healthy else None,
        "never_healthy": [r["seed"] for r in runs if r["healthy_after_s"] is None],
    }
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=2) + "\n")
    print(json.dumps({k: v for k, v in results.items() if k != "runs"}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
