"""The pose filter's cost per update as its considered static errors grow (issue 29).

Run: ``python -m bench.consider_cost_bench [--sources 0,1,2,5,10,20] [--updates N] [--output
FILE]`` (defaults: those source counts, 2,000 updates each; seconds; writes
``bench/results/consider_cost.json``).

:class:`~ubitrack_agent.services.algorithms.PoseKalmanFilter` with ``S`` inputs each telling
the static part of its covariance (``S = 0``: the live fusion's filter, every covariance
white), adaptive, fed round-robin at 90 updates a second of simulated time: the process time
per update (median of five blocks), against the module docstring's ``O((12 + 6 S)^3)``. The
poses are a fixed point with noise; only the cost is measured here (the consistency is
:mod:`bench.fusion_consistency_bench`'s).
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

from ubitrack_agent.services.algorithms import PoseKalmanFilter

OUTPUT = Path(__file__).parent / "results" / "consider_cost.json"
WHITE = np.diag([1e-6] * 3 + [1e-6] * 3)
STATIC = np.diag([1e-7] * 3 + [1e-7] * 3)
BLOCKS = 5


def update_us(sources: int, updates: int, seed: int = 0) -> float:
    """Median over :data:`BLOCKS` blocks of the process time of one update, in us."""
    rng = np.random.default_rng(seed)
    kalman = PoseKalmanFilter(0.02, 0.02, adaptive=True)
    rotation = np.array([0.0, 0.0, 0.0, 1.0])
    blocks = []
    step = 0
    for _ in range(BLOCKS):
        began = time.process_time()
        for _ in range(updates // BLOCKS):
            translation = np.array([1.0, 2.0, 3.0]) + rng.normal(0.0, 1e-3, 3)
            told = {"static": STATIC, "source": step % sources} if sources else {}
            whole = WHITE + STATIC if sources else WHITE
            kalman.update(step * 11_111_111, rotation, translation, whole, **told)
            step += 1
        blocks.append((time.process_time() - began) / (updates // BLOCKS))
    return 1e6 * float(np.median(blocks))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sources", default="0,1,2,5,10,20", help="considered inputs to try")
    parser.add_argument("--updates", type=int, default=2_000, help="updates per count")
    parser.add_argument("--output", type=Path, default=OUTPUT)
    args = parser.parse_args(argv)
    counts = [int(s) for s in args.sources.split(",")]
    rows = {count: update_us(count, args.updates) for count in counts}
    print("| considered inputs S | state size | us per update | per the S = 0 filter |")
    print("|---|---|---|---|")
    for count, us in rows.items():
        print(f"| {count} | {12 + 6 * count} | {us:.0f} | {us / rows[counts[0]]:.2f} |")
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(
        json.dumps(
            {
                "command": f"python -m bench.consider_cost_bench --sources {args.sources} "
                f"--updates {args.updates}",
                "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                "machine": {"python": platform.python_version(), "numpy": np.__version__},
                "update_us": {str(k): v for k, v in rows.items()},
            },
            indent=1,
        )
    )
    print(f"written to {args.output}")


if __name__ == "__main__":
    main()
