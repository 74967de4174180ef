"""Clock offset estimation (``net/clock.py``, ``services/clock_sync.py``) against known offsets.

Run: ``python -m bench.clock_bench [--seconds S] [--direct N]``. On loopback, with real zenoh
and real processes: an agent (no host manager of its own) and one host manager per injected
offset (``--clock-offset-ms``: -250, 0 and +400 ms, its clock reading that much ahead of the
agent's), all on one machine and so on one real clock, so the true offset of each is exactly
minus its injection. Two sets of figures, printed and written to
``bench/results/clock_bench.json``:

* **host managers:** every estimate each host manager makes during ``--seconds`` (one at once,
  then one every 10 s), read from its status: the error against the true offset, the estimate's
  uncertainty (half its best round trip) and that round trip, and how many errors were within
  the uncertainty (all of them, if the bound holds);
* **direct:** ``--direct`` estimates per offset made from this process with the same function
  the host managers use (8 exchanges, best round trip), for a larger sample of the error.

Loopback only: a network between hosts adds its delays and their asymmetry to the round trip
(the error stays within half of it).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from collections import Counter
from pathlib import Path
from typing import Any

from bench.dataflow_bench import Network, percentiles
from bench.report import write_results
from tests.integration.zenoh_helpers import wait_until
from ubitrack_agent.net.clock import Clock, measure_offset

RESULTS = Path(__file__).with_name("results") / "clock_bench.json"
OFFSETS_MS = (-250, 0, 400)
POLL_S = 0.5


def _status(net: Network, host: str) -> dict[str, Any] | None:
    payload = json.dumps({"op": "status"})
    replies = list(net.session.get(net.keys.host_request(host), payload=payload, timeout=2.0))
    if not replies or replies[0].ok is None:
        return None
    return json.loads(replies[0].ok.payload.to_bytes())


def _summary(errors_ns: list[int], uncertainties_ns: list[int], rtts_ns: list[int]) -> dict:
    """Errors, uncertainties and round trips in microseconds, and the errors within bound."""
    within = sum(abs(e) <= u for e, u in zip(errors_ns, uncertainties_ns, strict=True))
    return {
        "estimates": len(errors_ns),
        "abs_error_us": percentiles([abs(e) / 1e3 for e in errors_ns]),
        "uncertainty_us": percentiles([u / 1e3 for u in uncertainties_ns]),
        "rtt_us": percentiles([r / 1e3 for r in rtts_ns]),
        "within_uncertainty": within,
    }


def host_managers(net: Network, seconds: float) -> dict[str, Any]:
    """The estimates each host manager reports over ``seconds`` (a new one when its age
    restarts), by injected offset."""
    hosts = {
        offset: f"clock{offset:+d}".replace("+", "p").replace("-", "m") for offset in OFFSETS_MS
    }
    for offset, host in hosts.items():
        net.spawn(
            *("-m", "ubitrack_agent.services.host", "--name", host, "--pool-size", "0", "--quiet"),
            *("--clock-offset-ms", str(offset)),
        )
    seen: dict[int, list[dict[str, Any]]] = {offset: [] for offset in OFFSETS_MS}
    for host in hosts.values():
        wait_until(lambda host=host: (_status(net, host) or {}).get("clock"), timeout=60)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        for offset, host in hosts.items():
            clock = (_status(net, host) or {}).get("clock")
            estimates = seen[offset]
            if clock and (not estimates or clock["age_s"] < estimates[-1]["age_s"]):
                estimates.append(clock)
            elif clock and estimates:
                estimates[-1]["age_s"] = clock["age_s"]
        time.sleep(POLL_S)
    return {
        f"{offset:+d} ms": _summary(
            [e["offset_ns"] + offset * 10**6 for e in estimates],
            [e["uncertainty_ns"] for e in estimates],
            [e["rtt_ns"] for e in estimates],
        )
        for offset, estimates in seen.items()
    }


def direct(net: Network, count: int) -> dict[str, Any]:
    """``count`` estimates per injected offset from this process."""
    results = {}
    for offset in OFFSETS_MS:
        clock, counters = Clock(offset * 10**6), Counter[str]()
        estimates = []
        while len(estimates) < count:
            estimate = measure_offset(net.session, net.keys.agent_clock(), clock, counters)
            if estimate is not None:
                estimates.append(estimate)
            time.sleep(0.05)
        results[f"{offset:+d} ms"] = _summary(
            [e.offset_ns + offset * 10**6 for e in estimates],
            [e.uncertainty_ns for e in estimates],
            [e.rtt_ns for e in estimates],
        )
    return results


def main() -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.clock_bench", description=__doc__.split("\n")[0]
    )
    parser.add_argument(
        "--seconds", type=float, default=60.0, help="host managers observed (default 60)"
    )
    parser.add_argument(
        "--direct", type=int, default=100, help="direct estimates per offset (default 100)"
    )
    args = parser.parse_args()
    net = Network()
    try:
        net.spawn("-m", "ubitrack_agent.cli", "agent", "--no-host", "--quiet")
        wait_until(lambda: list(net.session.get(net.keys.agent_clock(), timeout=1.0)), timeout=60)
        results = {
            "date": time.strftime("%Y-%m-%d"),
            "machine": f"{os.cpu_count()} CPU, Python {platform.python_version()}",
            "transport": "loopback (one machine: the true offset is minus the injected one)",
            "command": f"python -m bench.clock_bench --seconds {args.seconds:g} "
            f"--direct {args.direct}",
            "host_managers": host_managers(net, args.seconds),
            "direct": direct(net, args.direct),
        }
    finally:
        net.close()
    write_results(RESULTS, results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
