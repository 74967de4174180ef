"""What judging each edge's silence costs a provider (``io.flowing``), as its edges grow.

Run: ``python -m bench.flowing_bench [--edges 1,10,100,1000] [--seconds S] [--rate HZ]``.
For each number of edges, a simulated stream: every edge published at ``--rate`` (60 Hz), its
samples spread over the interval with 2 ms of jitter and 2 % of them dropped (a simulated
A.R.T. tracker's), for ``--seconds`` of simulated time (10 s); the provider's checker runs at
each deadline :meth:`FlowingEdges.silent` gives, as the provider's thread does. Times are
simulated, costs are measured: the process time of all publications (:meth:`published`) and of
all checks (:meth:`silent`), per sample and per second of stream, the checks made, the edges
judged silent where two frames in a row were dropped (as ``io.flowing`` means them to be: two
frames missed), and the false alarms (judged silent otherwise: one dropped frame, jitter).
Prints a table and writes ``bench/results/flowing.json``.

Expected growth: O(1) a publication; O(log edges) per edge come due, about every two of its
intervals, so the checks per second grow as edges x rate, like the samples, not as their
square (a check going through every edge at each edge's deadline would).
"""

from __future__ import annotations

import argparse
import heapq
import random
import time
from pathlib import Path
from typing import Any

from bench.report import run_header, write_results
from ubitrack_agent.io.flowing import FlowingEdges

RESULTS = Path(__file__).with_name("results") / "flowing.json"
JITTER_S = 0.002
DROPPED = 0.02


def one_size(edges: int, seconds: float, rate: float, seed: int) -> dict[str, Any]:
    """The costs for ``edges`` edges (docstring)."""
    rng = random.Random(seed)
    names = [f"E{i}" for i in range(edges)]
    flowing = FlowingEdges(names)
    period = 1.0 / rate
    frames = int(seconds * rate)
    dropped = {name: {k for k in range(frames) if rng.random() < DROPPED} for name in names}
    samples = [
        (k * period + phase + rng.uniform(-JITTER_S, JITTER_S), name, k)
        for name, phase in zip(names, (rng.uniform(0, period) for _ in names), strict=True)
        for k in range(frames)
        if k not in dropped[name]
    ]
    heapq.heapify(samples)
    last = dict.fromkeys(names, -1)
    publish_s = check_s = 0.0
    checks = published = 0
    stops: list[bool] = []
    """Per edge judged silent: whether it was (the next two frames dropped)."""
    next_check: float | None = None
    while samples:
        at, name, k = heapq.heappop(samples)
        while next_check is not None and next_check <= at:
            started = time.process_time()
            stopped, next_check = flowing.silent(next_check)
            check_s += time.process_time() - started
            checks += 1
            stops += [{last[n] + 1, last[n] + 2} <= dropped[n] for n in stopped]
        started = time.process_time()
        if flowing.published(name, at):
            _, next_check = flowing.silent(at)
        publish_s += time.process_time() - started
        last[name], published = k, published + 1
    return {
        "edges": edges,
        "samples": published,
        "checks": checks,
        "checks_per_second": checks / seconds,
        "stops_at_two_dropped_frames": sum(stops),
        "false_alarms": len(stops) - sum(stops),
        "publish_us_per_sample": 1e6 * publish_s / published,
        "check_us_per_sample": 1e6 * check_s / published,
        "check_ms_per_second": 1e3 * check_s / seconds,
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--edges", default="1,10,100,1000", help="numbers of edges, a,b,...")
    parser.add_argument("--seconds", type=float, default=10.0, help="simulated seconds a size")
    parser.add_argument("--rate", type=float, default=60.0, help="each edge's rate (Hz)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    sizes = [one_size(int(n), args.seconds, args.rate, args.seed) for n in args.edges.split(",")]
    print(
        "| edges | samples | checks / s | stopped at two frames dropped | false alarms | "
        "publication us / sample | checks us / sample | checks ms / s of stream |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for size in sizes:
        print(
            f"| {size['edges']} | {size['samples']} | {size['checks_per_second']:.0f} | "
            f"{size['stops_at_two_dropped_frames']} | {size['false_alarms']} | "
            f"{size['publish_us_per_sample']:.2f} | "
            f"{size['check_us_per_sample']:.2f} | {size['check_ms_per_second']:.1f} |"
        )
    write_results(
        args.output,
        run_header()
        | {"command": "python -m bench.flowing_bench " + " ".join(argv or []), "sizes": sizes},
    )


if __name__ == "__main__":
    main()
