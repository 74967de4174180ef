"""A stalled reader against everyone else (issue 28, failure containment; issue 29, no gap): what
a container that stops reading (SIGSTOP: a hung process, a debugger, a machine swapping) costs
the container it reads from, with the data path's puts as they are (DROP, waiting at most
``net.config.DROP_WAIT_US``) and as they were until session 27 (a component's data key BLOCK).

Run: ``python -m bench.stall_bench [--stops 1,2,4,7] [--runs 3] [--rate 100] [--output FILE]``;
prints the figures and writes them to ``--output`` (default ``bench/results/stall.json``).

Everything is a real process on loopback with real zenoh (explicit endpoints, multicast off):
this process is the hub (as the agent is) and the sources; a host manager (``python -m
ubitrack_agent.services.host``) runs two containers as its zenoh clients, so it routes between
them: ``st-0`` holds two relays, ``producer`` (``src/p`` onto ``producer/out``) and ``other``
(``src/o`` onto ``other/out``, read by this process), and ``st-1`` holds ``consumer``, which
reads ``producer/out``. Both sources put a 48 KB sample (2,000 positions) every ``1 / --rate``
s; the processes' zenoh has 64 KB socket buffers and no shared memory (as
``tests/integration/test_congestion.py``), so a stopped reader's link fills within a second.
Each trial starts all of it afresh, waits until the consumer has read 20 samples, stops
``st-1`` for the trial's time and resumes it.

Per trial: the largest gap between two samples of ``other/out`` arriving here while ``st-1``
was stopped (counting from the stop to the first sample and from the last to the resume),
``other``'s samples in that time against the sources' puts, and after the resume whether the
consumer reads again within 20 s, its ``received`` and ``missed`` counters and ``producer``'s
``published``. The variant ``block`` runs the same with a zenoh file making the puts on
``producer``'s data key BLOCK (``qos/publication``, which overrides what a publisher was
declared with). Variants alternate within each run, and the order of the stops is the same.

Growth: O(samples) here; the trial's processes are started afresh (about 5 s each).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import signal
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.dataflow_bench import Network
from bench.report import run_header, write_results
from bench.throughput_bench import _host_up, start_groups
from tests.integration.zenoh_helpers import wait_until
from ubitrack_agent.core import encode
from ubitrack_agent.core.measurements import PositionList3D
from ubitrack_agent.net.host_protocol import Status, encode_request
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.session import CONFIG_VARIABLE
from ubitrack_agent.net.spec import ComponentSpec, GroupSpec, InputBinding
from ubitrack_agent.net.transport import fetch_latest

RESULTS = Path(__file__).with_name("results") / "stall.json"
HOST = "st"
POINTS = np.zeros((2_000, 3))
"""A sample's positions: 48 KB encoded."""
SMALL = {
    "link": {"tcp": {"so_rcvbuf": 65536, "so_sndbuf": 65536}},
    "shared_memory": {"enabled": False},
}
BLOCKING = {"key_exprs": ["**/data/producer/**"], "config": {"congestion_control": "block"}}
VARIANTS = {
    "drop": {"transport": SMALL},
    "block": {"transport": SMALL, "qos": {"publication": [BLOCKING]}},
}
"""The zenoh file of each variant's processes (``ZENOH_CONFIG``)."""
BACK_S = 20.0
"""How long the consumer may take to read again after the resume."""


def relay(keys: KeySpace, instance: str, source: str, chained: bool = False) -> ComponentSpec:
    """A relay of ``source`` onto its data key ``<instance>/out``."""
    return ComponentSpec(
        instance=instance,
        service="relay",
        inputs=(InputBinding("in", source, trigger=True, from_worker=chained),),
        outputs={"out": keys.data(f"{instance}/out")},
    )


def counters(net: Network, instance: str) -> dict[str, int]:
    """A component's counters (asked until its status answers, at most 30 s)."""

    def ask() -> dict[str, int] | None:
        payloads = fetch_latest(net.session, net.keys.status(instance), timeout=2.0)
        return json.loads(payloads[0])["counters"] if payloads else None

    return wait_until(ask, timeout=30)


def container_pid(net: Network, name: str) -> int:
    """The pid of container ``name``, from its host manager's status."""
    request = encode_request(Status())
    replies = list(net.session.get(net.keys.host_request(HOST), payload=request, timeout=5))
    return json.loads(replies[0].ok.payload.to_bytes())["containers"][name]["pid"]


def trial(stop_s: float, rate: float) -> dict[str, Any]:
    """One stop of ``st-1`` with everything started afresh (``ZENOH_CONFIG`` set by the
    caller); the figures of the module docstring."""
    net = Network()
    try:
        keys = net.keys
        net.spawn("-m", "ubitrack_agent.services.host", "--name", HOST, "--pool-size", "2",
                  "--quiet", "--log-level", "ERROR")  # fmt: skip
        wait_until(lambda: _host_up(net, HOST), timeout=60, interval=0.2)
        groups = {
            "st-0": GroupSpec("st-0", (relay(keys, "producer", keys.data("src/p")),
                                       relay(keys, "other", keys.data("src/o")))),
            "st-1": GroupSpec("st-1", (relay(keys, "consumer", keys.data("producer/out"),
                                             chained=True),)),
        }  # fmt: skip
        start_groups(net.session, keys, HOST, groups)
        arrivals: list[float] = []
        net.session.declare_subscriber(
            keys.data("other/out"), lambda _: arrivals.append(time.monotonic())
        )
        sources = {name: net.session.declare_publisher(keys.data(f"src/{name}")) for name in "po"}
        wait_until(lambda: all(p.matching_status.matching for p in sources.values()), timeout=60)
        stop, stamps, puts = threading.Event(), itertools.count(1_000), []

        def provide() -> None:
            while not stop.wait(1.0 / rate):
                stamp = next(stamps)
                for publisher in sources.values():
                    publisher.put(encode(PositionList3D(stamp, POINTS)))
                puts.append(time.monotonic())

        def consumer_received() -> int:
            return counters(net, "consumer").get("received", 0)

        provider = threading.Thread(target=provide, daemon=True)
        provider.start()
        pid = container_pid(net, "st-1")
        try:
            wait_until(lambda: consumer_received() >= 20, timeout=60)
            os.kill(pid, signal.SIGSTOP)
            stopped_at = time.monotonic()
            time.sleep(stop_s)
            resumed_at = time.monotonic()
            os.kill(pid, signal.SIGCONT)
            before = consumer_received()
            try:
                wait_until(lambda: consumer_received() >= before + 20, timeout=BACK_S)
                back_s: float | None = round(time.monotonic() - resumed_at, 2)
            except AssertionError:
                back_s = None
        finally:
            os.kill(pid, signal.SIGCONT)
            stop.set()
            provider.join()
        during = [t for t in arrivals if stopped_at <= t <= resumed_at]
        edges = [stopped_at, *during, resumed_at]
        consumer, producer = counters(net, "consumer"), counters(net, "producer")
        return {
            "stop_s": stop_s,
            "other_largest_gap_s": round(max(b - a for a, b in itertools.pairwise(edges)), 3),
            "other_received_during": len(during),
            "puts_during": sum(stopped_at <= t <= resumed_at for t in puts),
            "consumer_reads_again_after_s": back_s,
            "consumer_received": consumer.get("received", 0),
            "consumer_missed": consumer.get("missed", 0),
            "producer_published": producer.get("published", 0),
        }
    finally:
        net.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--stops", default="1,2,4,7", help="seconds st-1 is stopped, per trial")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--rate", type=float, default=100.0, help="samples/s per source")
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    stops = [float(s) for s in args.stops.split(",")]
    results: dict[str, Any] = {
        **run_header(),
        "rate_per_source": args.rate,
        "trials": {variant: [] for variant in VARIANTS},
    }
    previous = os.environ.get(CONFIG_VARIABLE)
    with tempfile.TemporaryDirectory() as scratch:
        for run in range(args.runs):
            order = list(VARIANTS) if run % 2 == 0 else list(reversed(VARIANTS))
            for stop_s in stops:
                for variant in order:
                    path = Path(scratch) / f"{variant}.json5"
                    path.write_text(json.dumps(VARIANTS[variant]))
                    os.environ[CONFIG_VARIABLE] = str(path)
                    row = {"run": run, **trial(stop_s, args.rate)}
                    results["trials"][variant].append(row)
                    print(variant, json.dumps(row), flush=True)
    if previous is None:
        os.environ.pop(CONFIG_VARIABLE, None)
    else:
        os.environ[CONFIG_VARIABLE] = previous
    results["load_average_after"] = [round(x, 2) for x in os.getloadavg()]
    results["summary"] = summary(results["trials"], stops)
    write_results(args.output, results)
    return 0


def summary(trials: dict[str, list[dict[str, Any]]], stops: list[float]) -> list[dict[str, Any]]:
    """Per variant and stop, the medians (and largest) of the other flow's gap, and how many
    trials the consumer read again in."""
    rows = []
    for variant, rows_of in trials.items():
        for stop_s in stops:
            of = [r for r in rows_of if r["stop_s"] == stop_s]
            if not of:
                continue
            gaps = [r["other_largest_gap_s"] for r in of]
            missed = [r["consumer_missed"] for r in of]
            rows.append(
                {
                    "variant": variant,
                    "stop_s": stop_s,
                    "other_largest_gap_s_median": round(float(np.median(gaps)), 3),
                    "other_largest_gap_s_max": max(gaps),
                    "consumer_missed_median": float(np.median(missed)),
                    "consumer_read_again": sum(
                        r["consumer_reads_again_after_s"] is not None for r in of
                    ),
                    "trials": len(of),
                }
            )
    return rows


if __name__ == "__main__":
    raise SystemExit(main())
