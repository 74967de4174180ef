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
check, ``whole``); up to ``--timeout`` seconds. Every sample the applications received from
the first fault to the end is judged against the truth (issue 29, ``chaos_faults.judged``):
how many were *wrong* (beyond 5 cm, 5 degrees or 3 sigma of their own covariance), the
largest errors and NEES, and the first wrong ones with the seconds since the fault before
them, their latency (arrival less stamp) and the stamp shift whose truth fits them best (a
value right for another time). Run::

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

import numpy as np

from bench.churn_bench import APPLICATIONS, POOL_SIZE, Applications, machine, system
from tests.integration.chaos_faults import THREE_SIGMA_NEES, Chaos, true_pose, whole
from ubitrack_agent.core import Measurement
from ubitrack_agent.net.keys import RelationId

RESULTS = Path(__file__).with_name("results") / "chaos_runs.json"
POLL_S = 0.25
HEALTHY_WITHIN_S = 10.0
"""The issue's bound on the time to healthy after the churn's end."""


WRONG_SHOWN = 5
"""Wrong samples listed per relation and run."""

SHIFTS_MS = range(-300, 301)
"""Stamp shifts tried on a wrong sample: which time's truth it matches best."""


def best_shift(relation: RelationId, sample: Measurement) -> tuple[int, float]:
    """The shift of ``sample``'s stamp (ms, in :data:`SHIFTS_MS`) whose truth is nearest its
    translation, and that distance (mm): a shift far from 0 with a small distance says the
    value is right for another time (a stamp or an extrapolation wrong), not wrong in space."""
    distances = {
        shift: float(
            np.linalg.norm(
                sample.translation - true_pose(relation, sample.timestamp_ns + shift * 1_000_000)[1]
            )
        )
        for shift in SHIFTS_MS
    }
    shift = min(distances, key=distances.__getitem__)
    return shift, round(distances[shift] * 1e3, 2)


def verdict(apps: Applications, chaos: Chaos, since: float) -> dict[str, Any]:
    """Per relation, the samples received from ``since`` (wall clock, s) judged against the
    truth: how many, how many wrong, the largest errors and NEES, the first wrong ones (seconds
    since the fault before, that fault, mm, degrees, NEES, latency ms, :func:`best_shift`'s
    shift ms and distance mm). ``O(samples)``."""
    faults = list(zip(chaos.times, chaos.log, strict=True))
    summary: dict[str, Any] = {}
    for relation, judgements in apps.judgements.items():
        received = [(arrived, j) for arrived, j in list(judgements) if arrived >= since]
        wrong = [(arrived, j) for arrived, j in received if j.wrong]
        shown = []
        for arrived, j in wrong[:WRONG_SHOWN]:
            before = [(at, fault) for at, fault in faults if at <= arrived]
            at, fault = before[-1] if before else (since, "none")
            nees = None if j.nees is None else round(j.nees, 1)
            sample = apps.wrong[relation][arrived]
            shift, distance = best_shift(relation, sample)
            latency = round((arrived - sample.timestamp_ns * 1e-9) * 1e3, 1)
            errors = [round(j.mm, 1), round(j.deg, 2), nees]
            shown.append([round(arrived - at, 2), fault, *errors, latency, shift, distance])
        values = [j.nees for _, j in received if j.nees is not None]
        summary[str(relation)] = {
            "samples": len(received),
            "wrong": len(wrong),
            "beyond_3_sigma": sum(v > THREE_SIGMA_NEES for v in values),
            "error_mm_max": round(max((j.mm for _, j in received), default=0.0), 2),
            "error_deg_max": round(max((j.deg for _, j in received), default=0.0), 3),
            "nees_max": round(max(values), 1) if values else None,
            "nees_mean": round(statistics.fmean(values), 2) if values else None,
            "first_wrong": shown,
        }
    return summary


def one_run(seed: int, events: int, timeout: float) -> dict[str, Any]:
    """A fresh system, ``events`` faults from ``seed``, then the time to healthy."""
    with system(POOL_SIZE, seed) as (chaos, apps):
        chaos.rng = random.Random(seed)
        load = os.getloadavg()[0]
        began = time.time()
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
            "samples": verdict(apps, chaos, began),
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
        "runs_without_a_wrong_sample": sum(
            all(judged["wrong"] == 0 for judged in r["samples"].values()) for r in runs
        ),
    }
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=2) + "\n")
    print(json.dumps({k: v for k, v in results.items() if k != "runs"}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
