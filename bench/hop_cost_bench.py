"""Where a pattern hop's time goes on a CPU that did something else since the last sample
(issue 12, ``docs/performance.md``, "Data path").

Run: ``python -m bench.hop_cost_bench [--samples N] [--gap-ms G] [--output FILE]``; prints
the figures and writes them to ``bench/results/hop_cost.json`` (or ``FILE``).

One process, one zenoh session with no peer (nothing leaves it). The same ErrorPoses, one
every ``--gap-ms`` (5 ms: a tracker's rate), are handled three ways, interleaved sample by
sample so the three see the same machine:

* ``worker``: ``Worker._deliver`` of a concatenation worker whose input comes from a worker
  (the dynamic ``BC`` composed with a static ``AB``), everything the live hop does after its
  input's thread takes the sample from zenoh's channel;
* ``package``: the package's own steps alone: ``decode`` at level ``WORKER``,
  ``compose_poses`` with the static input restamped, ``encode``, a zenoh put;
* ``minimal``: the same maths and checks written flat (msgpack, the arrays, finite numbers,
  a Cholesky, the means on floats, the covariance through the cached adjoint, msgpack, put),
  a lower bound for what a hop of this package must do.

Each handling is timed alone (``perf_counter``); the medians and their ratios are the figures.
The same three, back to back without a gap, show the warm cost.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
from scipy.linalg.lapack import dpotrf

from bench.dataflow_bench import STATIC, _concatenation_spec
from bench.report import write_results
from ubitrack_agent.core import ErrorPose, Pose, decode, encode, quaternions
from ubitrack_agent.core.measurements import WORKER
from ubitrack_agent.core.poses import compose_poses
from ubitrack_agent.core.uncertainty import adjoint as adjoint_of
from ubitrack_agent.net import config
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.session import open_session
from ubitrack_agent.services.worker import Worker

RESULTS = Path(__file__).with_name("results") / "hop_cost.json"


def samples(count: int, start_ns: int) -> list[bytes]:
    """``count`` encoded ErrorPoses 1 us apart with random positive definite covariances."""
    rng = np.random.default_rng(12)
    payloads = []
    for i in range(count):
        a = rng.normal(size=(6, 6)) * 1e-3
        cov = a @ a.T + np.eye(6) * 1e-6
        payloads.append(encode(ErrorPose(start_ns + 1000 * i, [0, 0, 0, 1], [0.1, 0.2, 0.3], cov)))
    return payloads


def minimal_hop(publisher: Any) -> Callable[[bytes], None]:
    """The hop's maths and checks with nothing around them (see the module docstring)."""
    q1, t1 = STATIC.rotation.tolist(), STATIC.translation.tolist()
    adjoint = adjoint_of(STATIC.rotation, STATIC.translation)
    adjoint_t = adjoint.T

    def hop(payload: bytes) -> None:
        message = msgpack.unpackb(payload)
        raw = message["rotation"] + message["translation"] + message["covariance"]
        if not all(map(math.isfinite, memoryview(raw).cast("d"))):
            return
        covariance = np.frombuffer(message["covariance"]).reshape(6, 6)
        if dpotrf(covariance, lower=1, clean=0)[1] != 0:
            return
        q2 = np.frombuffer(message["rotation"]).tolist()
        moved = quaternions.rotate_floats(q1, np.frombuffer(message["translation"]).tolist())
        q = np.array(quaternions.multiply_floats(q1, q2))
        t = np.array([moved[0] + t1[0], moved[1] + t1[1], moved[2] + t1[2]])
        out = STATIC.covariance + adjoint @ covariance @ adjoint_t
        result = {"v": 1, "type": "ErrorPose", "t": message["t"]}
        result.update(rotation=q.tobytes(), translation=t.tobytes(), covariance=out.tobytes())
        publisher.put(msgpack.packb(result))

    return hop


def package_hop(publisher: Any) -> Callable[[bytes], None]:
    def hop(payload: bytes) -> None:
        sample = decode(payload, (Pose, ErrorPose), WORKER)
        publisher.put(encode(compose_poses(STATIC.restamped(sample.timestamp_ns), sample)))

    return hop


def timed(hops: dict[str, Callable[[bytes], None]], payloads: list[bytes], gap_s: float):
    """Each payload handled by the next hop in turn, ``gap_s`` after the previous one (none:
    back to back); the handling times in us by hop."""
    names = list(hops)
    times: dict[str, list[float]] = {name: [] for name in names}
    for i, payload in enumerate(payloads):
        name = names[i % len(names)]
        if gap_s:
            time.sleep(gap_s)
        start = time.perf_counter()
        hops[name](payload)
        times[name].append((time.perf_counter() - start) * 1e6)
    return times


def summary(times: dict[str, list[float]]) -> dict[str, Any]:
    medians = {name: round(statistics.median(values), 1) for name, values in times.items()}
    return {
        "median_us": medians,
        "p90_us": {name: round(float(np.percentile(v, 90)), 1) for name, v in times.items()},
        "worker_over_minimal": round(medians["worker"] / medians["minimal"], 2),
        "package_over_minimal": round(medians["package"] / medians["minimal"], 2),
    }


def main() -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.hop_cost_bench")
    parser.add_argument("--samples", type=int, default=1500, help="per hop (default 1500)")
    parser.add_argument("--gap-ms", type=float, default=5.0, help="between samples (default 5)")
    parser.add_argument("--output", type=Path, default=RESULTS, help=f"(default {RESULTS})")
    args = parser.parse_args()
    keys = KeySpace("ubitrack/hopcost")
    with open_session(config.Settings(domain="hopcost")) as session:
        worker = Worker(_concatenation_spec(keys, "cost", from_worker=True), session, keys)
        generation = worker._generation
        worker._deliver(generation, 0, [encode(STATIC)])
        publisher = session.declare_publisher(keys.data("cost/elsewhere"))
        hops = {
            "worker": lambda payload: worker._deliver(generation, 1, [payload]),
            "package": package_hop(publisher),
            "minimal": minimal_hop(publisher),
        }
        end = 600 + 3 * args.samples
        payloads = samples(end + 600, time.time_ns())  # each newer than the one before
        timed(hops, payloads[:600], 0.0)  # imports and caches warmed
        cold = timed(hops, payloads[600:end], args.gap_ms / 1000)
        warm = timed(hops, payloads[end:], 0.0)
        published = worker.counters["published"]
        worker.stop()
        publisher.undeclare()
    if published != 200 + len(cold["worker"]) + len(warm["worker"]):
        raise SystemExit(f"the worker published {published} results, not one per sample")
    results = {
        "date": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
        "machine": f"{platform.machine()}, {platform.python_version()}",
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "samples_per_hop": args.samples,
        "gap_ms": args.gap_ms,
        "after_a_gap": summary(cold),
        "back_to_back": summary(warm),
    }
    write_results(args.output, results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
