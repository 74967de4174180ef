"""How soon an adapter stopped with SIGTERM is known to be gone: from the signal to its provider's
liveliness token leaving, as a subscriber on the hub sees it, and to the process's end.

Run: ``python -m bench.provider_leave_bench [--rounds N] [--compare-with CHECKOUT]``. Each round
starts ``ubitrack dtrack`` (no tracker sending: the adapter waits on its UDP port, as one whose
tracker was just switched off), waits for its token, lets it run ``--settle`` seconds, sends
SIGTERM and times the token's DELETE and the exit. With ``--compare-with``, rounds alternate
between this checkout and another one run by its own ``.venv/bin/python`` from its folder (a
``PYTHONPATH`` would take ``ubitrack_agent.services`` from this one: CONTRIBUTING.md). Figures
(ms, medians and ranges) are printed and written to ``bench/results/provider_leave.json``.

Why it matters: a producer of a relation key that needs the provider gives the key up when the
token leaves (``services.handover``, rule 7), so the time to the token's end is part of the gap
an application sees when a tracker leaves (``docs/performance.md``, "A holder that lost a
provider"). O(1) per round; nothing grows with the rounds.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from bench.dataflow_bench import Network
from bench.report import write_results
from tests.integration.zenoh_helpers import free_port, wait_until

RESULTS = Path(__file__).with_name("results") / "provider_leave.json"
PROVIDER = "leaving"


def one_round(net: Network, checkout: Path, python: str, settle_s: float) -> dict[str, float]:
    """One adapter started from ``checkout`` by ``python``, stopped by SIGTERM: ms to its
    token's DELETE and to its exit."""
    events: list[tuple[str, float]] = []
    watch = net.session.liveliness().declare_subscriber(
        net.keys.provider(PROVIDER), lambda s: events.append((str(s.kind), time.monotonic()))
    )
    adapter = subprocess.Popen(
        [
            python,
            *("-m", "ubitrack_agent.cli", "dtrack", "--quiet", "--provider", PROVIDER),
            *("--bind", "127.0.0.1", "--port", str(free_port()), "--body", "0=HT"),
            *net.flags(),
        ],
        cwd=checkout,
        stdin=subprocess.DEVNULL,
    )
    try:
        wait_until(lambda: bool(events), timeout=60)
        time.sleep(settle_s)
        signalled = time.monotonic()
        adapter.terminate()
        adapter.wait(timeout=30)
        ended = time.monotonic()
        wait_until(lambda: len(events) >= 2, timeout=30)
    finally:
        if adapter.poll() is None:
            adapter.kill()
            adapter.wait()
        watch.undeclare()
    return {
        "token_gone_ms": (events[1][1] - signalled) * 1e3,
        "process_ended_ms": (ended - signalled) * 1e3,
    }


def summary(rounds: list[dict[str, float]]) -> dict[str, Any]:
    return {
        name: {
            "median": statistics.median(r[name] for r in rounds),
            "min": min(r[name] for r in rounds),
            "max": max(r[name] for r in rounds),
        }
        for name in rounds[0]
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5, help="rounds per checkout")
    parser.add_argument("--settle", type=float, default=1.0, help="seconds before SIGTERM")
    parser.add_argument(
        "--compare-with", type=Path, help="another checkout with its own .venv, run alternately"
    )
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    here = Path(__file__).resolve().parent.parent
    checkouts = {"this": (here, sys.executable)}
    if args.compare_with is not None:
        other = args.compare_with.resolve()
        checkouts["other"] = (other, str(other / ".venv" / "bin" / "python"))
    net = Network()
    rounds: dict[str, list[dict[str, float]]] = {name: [] for name in checkouts}
    try:
        for _ in range(args.rounds):
            for name, (checkout, python) in checkouts.items():
                rounds[name].append(one_round(net, checkout, python, args.settle))
    finally:
        net.close()
    write_results(
        args.output,
        {
            "command": "python -m bench.provider_leave_bench "
            f"--rounds {args.rounds} --settle {args.settle:g}"
            + (f" --compare-with {args.compare_with}" if args.compare_with else ""),
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "machine": {"python": platform.python_version(), "cpus": os.cpu_count()},
            "load_average_end": os.getloadavg(),
            "checkouts": {name: str(checkout) for name, (checkout, _) in checkouts.items()},
            "summary": {name: summary(r) for name, r in rounds.items()},
            "rounds": rounds,
        },
    )


if __name__ == "__main__":
    main()
