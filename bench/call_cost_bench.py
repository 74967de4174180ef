"""What one call costs on a CPU that did something else since the last one (issue 12,
``docs/performance.md``, "Data path"): the pieces a pattern hop is made of, each alone.

Run: ``python -m bench.call_cost_bench [--calls N] [--gap-ms G]``; prints the figures and
writes them to ``bench/results/call_cost.json``.

Every piece runs in a process of its own, all of them at once (so each runs among the others,
as a hop's process runs among the flow's), calling its piece ``--calls`` times, ``--gap-ms``
apart (20 ms: a process of a flow of several hops, one sample every 5 ms to each), each call
timed alone (``perf_counter_ns``); then as many calls back to back. The medians are the
figures. A piece's cost after a gap is what its code and data cost to bring back; its cost
back to back what it computes.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import struct
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from scipy.linalg.lapack import dpotrf

from bench.report import write_results

RESULTS = Path(__file__).with_name("results") / "call_cost.json"

_RNG = np.random.default_rng(1)
_A = _RNG.normal(size=(6, 6))
_COVARIANCE = _A @ _A.T + np.eye(6)
_RAW = _COVARIANCE.tobytes()
_ADJOINT = _RNG.normal(size=(6, 6))
_ADJOINT_T = _ADJOINT.T
_FLOATS = [0.1, 0.2, 0.3, 0.9]
_FOUR = struct.Struct("4d")


def _nothing(x: int) -> int:
    return x


PIECES: dict[str, Callable[[], object]] = {
    "a Python call": lambda: _nothing(1),
    "np.array of 4 floats": lambda: np.array(_FLOATS),
    "np.frombuffer and reshape (6x6)": lambda: np.frombuffer(_RAW).reshape(6, 6),
    "np.frombuffer of 4 packed floats": lambda: np.frombuffer(_FOUR.pack(*_FLOATS)),
    "tolist of 4": lambda: _COVARIANCE[0, :4].tolist(),
    "setflags": lambda: _COVARIANCE.setflags(write=True),
    "dtype comparison": lambda: _COVARIANCE.dtype == np.float64,
    "LAPACK dpotrf (6x6)": lambda: dpotrf(_COVARIANCE, lower=1, clean=0),
    "covariance products and sum (6x6)": lambda: _COVARIANCE + _ADJOINT @ _COVARIANCE @ _ADJOINT_T,
}
"""The pieces, by name; each a call of a hop (``bench.hop_cost_bench``'s ``minimal`` and
``package`` ways, ``core.codec``, ``core.poses``)."""


def time_piece(name: str, calls: int, gap_s: float) -> dict[str, float]:
    """Median us of ``calls`` calls of piece ``name`` ``gap_s`` apart, then back to back."""
    piece = PIECES[name]
    for _ in range(50):  # imports and first-call caches
        piece()
    times: dict[str, list[float]] = {"after_a_gap_us": [], "back_to_back_us": []}
    for label, gap in (("after_a_gap_us", gap_s), ("back_to_back_us", 0.0)):
        for _ in range(calls):
            if gap:
                time.sleep(gap)
            start = time.perf_counter_ns()
            piece()
            times[label].append((time.perf_counter_ns() - start) / 1000)
    return {label: round(statistics.median(values), 2) for label, values in times.items()}


def main() -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.call_cost_bench")
    parser.add_argument("--calls", type=int, default=500, help="per piece (default 500)")
    parser.add_argument("--gap-ms", type=float, default=20.0, help="between calls (default 20)")
    parser.add_argument("--piece", choices=list(PIECES), help=argparse.SUPPRESS)  # one child
    args = parser.parse_args()
    if args.piece is not None:
        print(json.dumps(time_piece(args.piece, args.calls, args.gap_ms / 1000)))
        return 0
    timing = ("--calls", str(args.calls), "--gap-ms", str(args.gap_ms))
    children = {
        name: subprocess.Popen(
            [sys.executable, "-m", "bench.call_cost_bench", "--piece", name, *timing],
            stdout=subprocess.PIPE,
            text=True,
        )
        for name in PIECES
    }
    pieces = {}
    for name, child in children.items():
        output, _ = child.communicate()
        if child.returncode != 0:
            raise SystemExit(f"{name}: the child failed ({child.returncode})")
        pieces[name] = json.loads(output)
    write_results(
        RESULTS,
        {
            "date": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
            "machine": f"{os.cpu_count()} CPU, Python {platform.python_version()}",
            "load_average": [round(x, 2) for x in os.getloadavg()],
            "calls_per_piece": args.calls,
            "gap_ms": args.gap_ms,
            "pieces": pieces,
        },
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
