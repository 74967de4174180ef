"""What a run of samples costs to decode against the same samples one by one
(``core.codec.decode_run``, ``decode``; ``docs/performance.md``, "Throughput, session 22").

Run: ``python -m bench.decode_run_bench [--repeat 5] [--output FILE]``; prints the figures and
writes them to ``--output``, by default ``bench/results/decode_run.json``.

One process, SciPy imported (as in a worker). Runs of 1, 8, 32 and 64 encoded ErrorPoses (random
unit quaternions, translations and covariances ``A A^T + 1e-6 I``), decoded at the levels
``FULL`` (a value from outside: a provider's sample, an application's relation) and ``WORKER``
(a worker's output): by ``decode_run`` for the run, and by ``decode`` for each. Each way is
timed 50 times in a row, best of ``--repeat``, and given in microseconds a sample. Growth: O(run)
for both; ``decode_run`` checks a run's numbers and covariances by a few numpy calls for the run
where its checks have a stacked form (``core.measurements.stacked_check``), else each alone.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
import timeit
from pathlib import Path
from typing import Any

import numpy as np
import scipy  # noqa: F401  (a worker's process: the covariance check uses SciPy's LAPACK)

from bench.report import write_results
from ubitrack_agent.core import ErrorPose, decode, encode
from ubitrack_agent.core.codec import decode_run
from ubitrack_agent.core.measurements import FULL, WORKER

RESULTS = Path(__file__).with_name("results") / "decode_run.json"
RUNS = (1, 8, 32, 64)
CALLS = 50


def payloads(count: int) -> list[bytes]:
    """``count`` encoded ErrorPoses of random values (seeded)."""
    rng = np.random.default_rng(1)
    found = []
    for i in range(count):
        a, q = rng.normal(size=(6, 6)) * 1e-3, rng.normal(size=4)
        covariance = a @ a.T + np.eye(6) * 1e-6
        value = ErrorPose(i + 1, q / np.linalg.norm(q), rng.normal(size=3), covariance)
        found.append(encode(value))
    return found


def us_per_sample(call: Any, count: int, repeat: int) -> float:
    """The best of ``repeat`` timings of ``CALLS`` calls, in us a sample."""
    return round(min(timeit.repeat(call, number=CALLS, repeat=repeat)) / CALLS / count * 1e6, 2)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.decode_run_bench")
    parser.add_argument("--repeat", type=int, default=5, help="timings, the best kept (5)")
    parser.add_argument("--output", type=Path, default=RESULTS, help=f"(default {RESULTS})")
    args = parser.parse_args(argv)
    every = payloads(max(RUNS))
    results: dict[str, Any] = {
        "date": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
        "machine": f"{platform.machine()}, Python {platform.python_version()}, "
        f"{os.cpu_count()} cores",
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "us_per_sample": {},
    }
    for level in (FULL, WORKER):
        for count in RUNS:
            run = every[:count]
            figures = {
                "decode_run": us_per_sample(
                    lambda run=run, level=level: decode_run(run, ErrorPose, level),
                    count,
                    args.repeat,
                ),
                "decode_each": us_per_sample(
                    lambda run=run, level=level: [decode(p, ErrorPose, level) for p in run],
                    count,
                    args.repeat,
                ),
            }
            results["us_per_sample"][f"{level}, run of {count}"] = figures
    write_results(args.output, results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
