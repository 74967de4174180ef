"""Worker start-up, cold and from the warm pool (the figure quoted in ``services/host.py``).

Run: ``python -m bench.worker_start [--trials N]``. Everything on loopback with real zenoh;
figures in ms are printed and written to ``bench/results/worker_start.json``.

* **Cold:** from spawning ``python -m ubitrack_agent.services.worker --spec ...`` to its liveliness
token, as
  seen by the bench: the interpreter, the imports (numpy, scipy, OpenCV), the zenoh session.
* **Warm:** a host manager (``python -m ubitrack_agent.services.host --pool-size 1``) with its pool
member
  ready; from sending the start request to the worker's token. The instance is then stopped,
  its process returns to the pool, and the next trial waits until it is ready again.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import queue
import time
from pathlib import Path
from typing import Any

from bench.dataflow_bench import Network, percentiles
from bench.report import write_results
from tests.integration.zenoh_helpers import wait_until
from ubitrack_agent.net.host_protocol import Start, Status, Stop, encode_request
from ubitrack_agent.net.spec import ComponentSpec, InputBinding

RESULTS = Path(__file__).with_name("results") / "worker_start.json"
HOST = "bench"


def _relay(net: Network, instance: str) -> ComponentSpec:
    return ComponentSpec(
        instance=instance,
        service="relay",
        inputs=(InputBinding("in", net.keys.data("bench/in"), trigger=True),),
        outputs={"out": net.keys.data(f"{instance}/out")},
    )


class TokenClock:
    """When worker tokens appear, on the bench's clock (the callback only queues)."""

    def __init__(self, net: Network) -> None:
        self._keys = net.keys
        self._appeared: queue.SimpleQueue[tuple[str, str, int]] = queue.SimpleQueue()
        self._watch = net.session.liveliness().declare_subscriber(
            net.keys.all_workers(),
            lambda s: self._appeared.put((str(s.kind), str(s.key_expr), time.perf_counter_ns())),
        )

    def wait(self, instance: str) -> int:
        """The time ``instance``'s token appeared (waiting for it)."""
        while True:
            kind, key, at = self._appeared.get(timeout=60)
            if kind.endswith("PUT") and self._keys.parse_worker(key)[0] == instance:
                return at


def cold(trials: int) -> list[float]:
    net = Network()
    tokens = TokenClock(net)
    times = []
    try:
        for trial in range(trials):
            spec = _relay(net, f"cold{trial}")
            spawned = time.perf_counter_ns()
            process = net.spawn("-m", "ubitrack_agent.services.worker", "--spec", spec.to_json())
            times.append((tokens.wait(spec.instance) - spawned) / 1e6)
            process.terminate()
            process.wait()
    finally:
        net.close()
    return times


def warm(trials: int) -> list[float]:
    net = Network()
    tokens = TokenClock(net)
    net.spawn("-m", "ubitrack_agent.services.host", "--name", HOST, "--pool-size", "1")
    request_key = net.keys.host_request(HOST)

    def ask(request: Any) -> dict[str, Any]:
        replies = list(net.session.get(request_key, payload=encode_request(request), timeout=5.0))
        if not replies or replies[0].ok is None:
            return {}
        return json.loads(replies[0].ok.payload.to_bytes())

    times = []
    try:
        for trial in range(trials):
            wait_until(lambda: ask(Status()).get("pool_ready") == 1, timeout=60)
            spec = _relay(net, f"warm{trial}")
            sent = time.perf_counter_ns()
            ask(Start(spec))
            times.append((tokens.wait(spec.instance) - sent) / 1e6)
            ask(Stop(spec.instance))
    finally:
        net.close()
    return times


def main() -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.worker_start", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--trials", type=int, default=10, help="starts of each kind (default 10)")
    args = parser.parse_args()
    results = {
        "date": time.strftime("%Y-%m-%d"),
        "machine": f"{os.cpu_count()} CPU, Python {platform.python_version()}",
        "cold_start_ms": percentiles(cold(args.trials)),
        "pool_start_ms": percentiles(warm(args.trials)),
    }
    write_results(RESULTS, results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
