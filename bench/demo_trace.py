"""What the demo's application receives around the A.R.T. tracker's return (issue 29): one
``ubitrack demo --json`` with a plain zenoh client beside it recording every sample on the
relation's key (its arrival, stamp, error against the truth, covariance, NEES), the tracker's
liveliness token, the agent's control commands, the workers' tokens and the first sample on
each data key, and printing them in time order from before the tracker's token to after its
first measurement.

Run: ``python -m bench.demo_trace [--phase-seconds S] [--before-ms B] [--after-ms A]``
(defaults 5 s, 300 ms before the token, 300 ms after the first measurement; about a minute).
Writes ``bench/results/demo_trace.json`` (the printed timeline). The simulator's truth serves
only the errors. O(samples) to record and print.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.fusion_latency_bench import _free_port, errors
from bench.report import write_results
from bench.switch_bench import C_A, Trace, truth_at
from bench.synthetic import nees
from ubitrack_agent.core import decode
from ubitrack_agent.core.errors import MeasurementError
from ubitrack_agent.net import config
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.session import open_session
from ubitrack_agent.sim_trackers.scenario import load_scenario

RESULTS = Path(__file__).parent / "results" / "demo_trace.json"
JOIN_S = 3.0
"""How long after starting the demo this client joins its network (the hub must listen)."""


def record(phase_seconds: float) -> tuple[list[tuple[int, Any]], Trace, str]:
    """Run the demo with this client beside it: the samples on C->A (arrival ns, sample),
    the :class:`~bench.switch_bench.Trace` and the key root."""
    port = _free_port("tcp")
    flags = ["--listen", f"tcp/127.0.0.1:{port}", "--domain", f"demotrace{port}"]
    demo = subprocess.Popen(
        [
            *(sys.executable, "-m", "ubitrack_agent.cli", "demo", "--json"),
            *("--phase-seconds", str(phase_seconds), *flags),
        ],
        stdout=subprocess.DEVNULL,
    )
    parser = argparse.ArgumentParser()
    config.add_arguments(parser)
    hub = config.from_arguments(parser.parse_args(flags), role="hub")
    keys, wire, trace = KeySpace(hub.key_prefix), [], Trace()
    lock = threading.Lock()

    def take(zenoh_sample: Any) -> None:
        arrived = time.time_ns()
        try:
            sample = decode(zenoh_sample.payload.to_bytes())
        except MeasurementError:
            return
        with lock:
            wire.append((arrived, sample))

    time.sleep(JOIN_S)
    with open_session(config.member_of(hub)) as session:
        watching = [session.declare_subscriber(keys.relation(C_A), take)]
        watching += trace.declare(session, keys)
        demo.wait()
        for subscriber in watching:
            subscriber.undeclare()
    if demo.returncode != 0:
        raise SystemExit(f"the demo exited {demo.returncode}")
    return wire, trace, keys.root


def timeline(
    wire: list[tuple[int, Any]], trace: Trace, root: str, before_ms: float, after_ms: float
) -> list[list[Any]]:
    """From ``before_ms`` before the tracker's last token to ``after_ms`` after its first
    measurement then: ms after that measurement, what."""
    world = load_scenario(None).world
    art = f"{root}/provider/ART"
    token = max(t for t, what, key in trace.items if key == art and "PUT" in what)
    measured = min(
        t for t, what, key in trace.items if what == "data" and "/data/ART/" in key and t > token
    )
    start, end = token - before_ms * 1e6, measured + after_ms * 1e6
    rows: list[tuple[int, str]] = []
    firsts: dict[str, int] = {}
    for t, what, key in trace.items:
        if not start <= t <= end:
            continue
        if what == "data":
            firsts.setdefault(key, t)
        elif what != "relation":
            rows.append((t, f"{what} {key.removeprefix(root + '/')}"))
    rows += [(t, f"first data {key.removeprefix(root + '/')}") for key, t in firsts.items()]
    for arrived, sample in wire:
        if start <= arrived <= end:
            mm, deg = errors(sample, world, sample.timestamp_ns)
            value = nees(sample, truth_at(world, sample.timestamp_ns))
            trace_mm2 = float(np.trace(sample.covariance[3:, 3:])) * 1e6
            rows.append(
                (
                    arrived,
                    f"sample: latency {(arrived - sample.timestamp_ns) / 1e6:.1f} ms, error "
                    f"{mm:.2f} mm {deg:.3f} deg, position covariance trace {trace_mm2:.1f} mm2, "
                    f"NEES {value:.1f}",
                )
            )
    return [[round((t - measured) / 1e6, 1), what] for t, what in sorted(rows)]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--phase-seconds", type=float, default=5.0)
    parser.add_argument("--before-ms", type=float, default=300.0)
    parser.add_argument("--after-ms", type=float, default=300.0)
    args = parser.parse_args(argv)
    wire, trace, root = record(args.phase_seconds)
    rows = timeline(wire, trace, root, args.before_ms, args.after_ms)
    write_results(
        RESULTS,
        {
            "command": "python -m bench.demo_trace",
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "timeline_ms_after_first_measurement": rows,
        },
    )
    for at, what in rows:
        print(f"{at:8.1f} ms  {what}")


if __name__ == "__main__":
    main()
