"""What a hop between two components of one container costs, and how soon a component added
to a running container computes (issue 28, ``services/container.py``).

Run: ``python -m bench.container_hop_bench [--samples N] [--adds N] [--output FILE]``; prints
the figures and writes them to ``--output`` (default ``bench/results/container_hop.json``).

1. **Hop** (one process, one zenoh session with no peer: nothing leaves it). A container runs
   a chain of :data:`CHAIN` concatenations, each composing the previous one's output (handed
   over as an object, ``ubitrack_agent.services.local_wires``) with a static edge; a value handed to
   the first runs down the chain on the calling thread to a sink reading the last one's output
   in the process. The time from the hand-over into the first to the sink, divided by the
   hops, is a hop's cost (each value timed alone, median); beside it, the same maths
   (``compose_poses`` with the static edge restamped) called directly in one loop. Interleaved
   sample by sample, back to back and after a gap of ``--gap-ms`` (a CPU that did something
   else since: a tracker's rate). Targets (issue 28): a hop <= 30 us, and within 1.25x of the
   direct maths for the figure-6 flow.
2. **Figure 6's A.R.T. path**: an inversion of the tracker's pose, then two concatenations
   with calibrations (paper, figure 6), each its own component in one container (as the agent
   runs them), against ``invert_pose`` and two ``compose_poses`` in a loop.
   The fusion that follows (two dynamic inputs, a trigger held for the other) is not in it.
3. **Add**: a container process (``python -m ubitrack_agent.services.container``) runs a relay of a
provider
   publishing every millisecond; an ``{"add": [...]}`` command on its control key starts an
   inversion reading the relay's output in the process. Timed from just before the command is
   put to the first output of the new component arriving at this process (a subscriber
   declared before): the command's trip, the component's start and its first computation, and
   up to a millisecond waiting for the provider's next sample. Removed again, ``--adds`` times.
   The container's cold start (spawn to its first component's liveliness token) beside it.
4. **Threads**: a container in this process (a zenoh session with no peer) given
   ``--components`` components, chains of two concatenations as in ``bench.throughput_bench``
   (the first reading a provider's key over zenoh and a static edge, the second the first's
   output in the process and a static edge, its output also on an application's relation
   key), added one chain at a time: the threads of the process it added (``/proc/self/task``,
   per component, by name), and the time an ``add`` took per component. The static edges
   are not published, so each component keeps asking for them (as one waiting for a
   calibration) while it is counted.
5. **Time queries** (in part 1's process, its chain of concatenations): the last component
   asked for times between its newest samples (each answer interpolated, composed and
   encoded), 200 times whatever ``--samples``: its ``at`` called directly
   (``Worker._ask``), and a query ``<key>?t=`` through zenoh in the same session, answered on
   the process's answering threads (``net.transport.ANSWERS``): what a query costs beyond the
   lookup (the hand-off from zenoh's thread, the reply). Then a publisher whose ``at`` does
   nothing, asked 1,000 times for a time and for its latest value from a second session in
   the process (loopback) and from its own: the hand-over alone.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import queue
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.container_add_bench import chain
from bench.report import write_results
from ubitrack_agent.core import ErrorPose, Measurement, Pose, encode
from ubitrack_agent.core.poses import compose_poses, invert_pose
from ubitrack_agent.net import config
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.session import open_session
from ubitrack_agent.net.spec import ComponentSpec, GroupSpec, InputBinding
from ubitrack_agent.net.time_queries import fetch_at
from ubitrack_agent.net.transport import LatestValuePublisher, fetch_latest
from ubitrack_agent.services.container import Container

RESULTS = Path(__file__).with_name("results") / "container_hop.json"
CHAIN = 5
"""Concatenations in the chain of part 1."""
RNG = np.random.default_rng(28)


def error_pose(t_ns: int) -> ErrorPose:
    a = RNG.normal(size=(6, 6)) * 1e-3
    q = RNG.normal(size=4)
    return ErrorPose(t_ns, q / np.linalg.norm(q), RNG.normal(size=3), a @ a.T + np.eye(6) * 1e-6)


def stage(keys: KeySpace, instance: str, source: str, service: str = "concatenation"):
    """A component reading ``source`` in the container: a concatenation with the static edge
    ``bench/<instance>/static``, or an inversion."""
    if service == "inversion":
        inputs = (InputBinding("AB", source, trigger=True, from_worker=True),)
        return ComponentSpec(instance, "inversion", inputs, {"BA": keys.data(f"{instance}/out")})
    inputs = (
        InputBinding("AB", keys.data(f"bench/{instance}/static"), static=True),
        InputBinding("BC", source, trigger=True, from_worker=True),
    )
    return ComponentSpec(instance, "concatenation", inputs, {"AC": keys.data(f"{instance}/out")})


def in_process_chain(session: Any, keys: KeySpace, services: list[str], statics: list[ErrorPose]):
    """A container running ``services`` in a chain, each static edge given; the function
    handing a value to the first and returning once the sink has it, and the container."""
    specs = []
    source = keys.data("bench/in")
    for index, service in enumerate(services):
        specs.append(stage(keys, f"hop{index}", source, service))
        source = keys.data(f"hop{index}/out")
    container = Container(session, keys, "bench", components=specs)
    workers = [container.components[spec.instance].worker for spec in specs]
    concatenations = [w for w in workers if w.spec.service == "concatenation"]
    for worker, static in zip(concatenations, statics, strict=True):
        worker._deliver(worker._generation, 0, [encode(static)])
    received: list[Measurement] = []
    container.wires.subscribe(source, received.extend)
    first = workers[0]
    trigger = len(first.spec.inputs) - 1

    def through(value: Measurement) -> Measurement:
        first._deliver_values(first._generation, trigger, [value])
        return received.pop()

    return through, container


def direct_maths(services: list[str], statics: list[ErrorPose]):
    def through(value: Measurement) -> Measurement:
        edges = iter(statics)
        t = value.timestamp_ns
        for service in services:
            if service == "inversion":
                value = invert_pose(value)
            else:
                value = compose_poses(next(edges).restamped(t), value)
        return value

    return through


def timed(ways: dict[str, Any], values: list[Measurement], gap_s: float) -> dict[str, list[float]]:
    """Each value through every way in turn (interleaved), each timed alone, in us."""
    times: dict[str, list[float]] = {name: [] for name in ways}
    for value in values:
        for name, through in ways.items():
            if gap_s:
                time.sleep(gap_s)
            start = time.perf_counter()
            through(value)
            times[name].append((time.perf_counter() - start) * 1e6)
    return times


def per_hop(times: dict[str, list[float]], hops: int) -> dict[str, Any]:
    medians = {name: statistics.median(values) / hops for name, values in times.items()}
    return {
        "median_us_per_hop": {name: round(value, 1) for name, value in medians.items()},
        "p90_us_per_hop": {
            name: round(float(np.percentile(values, 90)) / hops, 1)
            for name, values in times.items()
        },
        "container_over_direct": round(medians["container"] / medians["direct"], 2),
    }


def hop_costs(samples: int, gap_ms: float) -> dict[str, Any]:
    results: dict[str, Any] = {}
    keys = KeySpace("ubitrack/containerhop")
    flows = {
        "concatenation_chain": ["concatenation"] * CHAIN,
        "figure6_art_path": ["inversion", "concatenation", "concatenation"],
    }
    with open_session(config.Settings(domain="containerhop")) as session:
        for name, services in flows.items():
            statics = [error_pose(1) for s in services if s == "concatenation"]
            container_way, container = in_process_chain(session, keys, services, statics)
            ways = {"container": container_way, "direct": direct_maths(services, statics)}
            start = time.time_ns()
            values = [error_pose(start + 1000 * i) for i in range(300 + 2 * samples)]
            check = values[0]
            np.testing.assert_allclose(  # both ways compute the same
                container_way(check).covariance, ways["direct"](check).covariance, rtol=1e-12
            )
            timed(ways, values[1:300], 0.0)  # warmed
            warm = timed(ways, values[300 : 300 + samples], 0.0)
            cold = timed(ways, values[300 + samples :], gap_ms / 1000)
            first = container.components["hop0"].worker
            published = sum(e.worker.counters["published"] for e in container.components.values())
            if published != len(services) * len(values):
                raise SystemExit(f"{name}: {published} outputs, not one per value and hop")
            results[name] = {
                "services": services,
                "back_to_back": per_hop(warm, len(services)),
                "after_a_gap": per_hop(cold, len(services)),
                "encoded_by_first": first.counters["published"] - first.counters["not_sent"],
            }
            if name == "concatenation_chain":
                results["time_queries"] = time_queries(session, keys, container, values)
            container.stop()
            container.remove(list(container.components))
    results["query_hand_over"] = query_hand_over()
    return results


def time_queries(
    session: Any, keys: KeySpace, container: Container, values: list[Measurement]
) -> dict[str, Any]:
    """Part 5 of the module docstring: the chain's last component asked for times between
    its newest samples (interpolated), its ``at`` called directly and as a query."""
    last = f"hop{CHAIN - 1}"
    worker = container.components[last].worker
    key = keys.data(f"{last}/out")
    times = [value.timestamp_ns + 500 for value in values[-41:-1]] * 5  # between two samples
    direct, asked = [], []
    for t in times:
        start = time.perf_counter()
        worker._ask("AC", t)
        direct.append((time.perf_counter() - start) * 1e6)
        start = time.perf_counter()
        fetch_at(session, key, t, timeout=1.0)
        asked.append((time.perf_counter() - start) * 1e6)
    return {
        "queries": len(times),
        "at_us": {"median": round(statistics.median(direct), 1), "max": round(max(direct), 1)},
        "query_us": {
            "median": round(statistics.median(asked), 1),
            "p90": round(float(np.percentile(asked, 90)), 1),
        },
    }


def query_hand_over(queries: int = 1000) -> dict[str, Any]:
    """Part 5, second half: a publisher whose ``at`` does nothing, asked ``queries`` times
    for a time and for its latest value from a second session in this process (over
    loopback), and from its own session (the callback then runs on the asking thread)."""
    from tests.integration.zenoh_helpers import free_port

    port = free_port()
    hub = config.Settings(listen=(f"tcp/127.0.0.1:{port}",), domain="handover")
    member = config.Settings(
        connect=(f"tcp/127.0.0.1:{port}",), listen=("tcp/127.0.0.1:0",), domain="handover"
    )
    results: dict[str, Any] = {"queries": queries}
    with open_session(hub) as asker, open_session(member) as session:
        publisher = LatestValuePublisher(session, "bench/handover", lambda t: b"x")
        publisher.put(b"latest")
        for name, querier in (("across_sessions", asker), ("same_session", session)):
            while not fetch_latest(querier, "bench/handover"):
                time.sleep(0.01)
            timed_at, latest = [], []
            for _ in range(queries):
                start = time.perf_counter()
                fetch_at(querier, "bench/handover", 5, timeout=1.0)
                timed_at.append((time.perf_counter() - start) * 1e6)
                start = time.perf_counter()
                fetch_latest(querier, "bench/handover")
                latest.append((time.perf_counter() - start) * 1e6)
            results[name] = {
                "time_query_median_us": round(statistics.median(timed_at), 1),
                "latest_median_us": round(statistics.median(latest), 1),
            }
        publisher.undeclare()
    return results


def add_latency(adds: int) -> dict[str, Any]:
    """Part 3 of the module docstring, with a hub in this process and a container process."""
    from tests.integration.zenoh_helpers import free_port, member_flags

    port = free_port()
    domain = f"add{port}"
    keys = KeySpace(f"ubitrack/{domain}")
    relay = ComponentSpec(
        "src",
        "relay",
        (InputBinding("in", keys.data("provider/in"), trigger=True),),
        {"out": keys.data("src/out")},
    )
    settings = config.Settings(listen=(f"tcp/127.0.0.1:{port}",), domain=domain)
    with open_session(settings) as session:
        started = queue.SimpleQueue()
        watcher = session.liveliness().declare_subscriber(
            keys.worker_tokens("src"), lambda s: started.put(time.perf_counter()), history=True
        )
        spawned = time.perf_counter()
        process = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "ubitrack_agent.services.container",
                "--group",
                GroupSpec("box", (relay,)).to_json(),
                *member_flags(port, domain),
            ]
        )
        try:
            cold_s = started.get(timeout=60) - spawned
            watcher.undeclare()
            stop = threading.Event()
            provider = session.declare_publisher(keys.data("provider/in"))
            threading.Thread(target=_provide, args=(provider, stop), daemon=True).start()
            times = [_one_add(session, keys, i) for i in range(adds)]
            stop.set()
        finally:
            process.terminate()
            process.wait(timeout=10)
    return {
        "cold_container_start_s": round(cold_s, 2),
        "add_to_first_output_ms": {
            "median": round(statistics.median(times), 1),
            "max": round(max(times), 1),
            "min": round(min(times), 1),
            "runs": len(times),
        },
    }


def _provide(publisher: Any, stop: threading.Event) -> None:
    while not stop.wait(0.001):
        publisher.put(encode(Pose(time.time_ns(), [0, 0, 0, 1], [1.0, 2.0, 3.0])))


def _one_add(session: Any, keys: KeySpace, index: int) -> float:
    """Milliseconds from an add command to the new component's first output here."""
    instance = f"new{index}"
    arrived: queue.SimpleQueue[float] = queue.SimpleQueue()
    subscriber = session.declare_subscriber(
        keys.data(f"{instance}/out"), lambda s: arrived.put(time.perf_counter())
    )
    time.sleep(0.2)  # the subscriber known to the container before the clock starts
    spec = stage(keys, instance, keys.data("src/out"), "inversion")
    start = time.perf_counter()
    session.put(keys.control("box"), json.dumps({"add": [spec.as_dict()]}))
    first = arrived.get(timeout=10)
    subscriber.undeclare()
    session.put(keys.control("box"), json.dumps({"remove": [instance]}))
    time.sleep(0.1)
    return (first - start) * 1e3


def threads(components: int) -> dict[str, Any]:
    """Part 4 of the module docstring."""
    keys = KeySpace("ubitrack/containerthreads")

    with open_session(config.Settings(domain="containerthreads")) as session:
        before = set(os.listdir("/proc/self/task"))
        names_before = {thread.ident for thread in threading.enumerate()}
        container = Container(session, keys, "threads")
        start = time.perf_counter()
        for k in range(components // 2):
            container.add(chain(keys, k))
        add_s = time.perf_counter() - start
        time.sleep(1.0)
        added = len(set(os.listdir("/proc/self/task")) - before)
        kinds: dict[str, int] = {}
        for thread in threading.enumerate():
            if thread.ident not in names_before:
                kind = "zenoh callback" if "pyo3" in thread.name else thread.name.split(" ")[0]
                kind = kind.split(":")[0].split("-")[0].rstrip("_0123456789")
                kinds[kind] = kinds.get(kind, 0) + 1
        container.stop()
        container.remove(list(container.components))
    count = 2 * (components // 2)
    return {
        "components": count,
        "threads_added": added,
        "threads_per_component": round(added / count, 2),
        "python_threads_by_kind": kinds,
        "add_ms_per_component": round(add_s * 1e3 / count, 2),
    }


def main() -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.container_hop_bench")
    parser.add_argument("--samples", type=int, default=2000, help="per way (default 2000)")
    parser.add_argument("--gap-ms", type=float, default=2.0, help="the gap (default 2)")
    parser.add_argument("--adds", type=int, default=30, help="add commands timed (default 30)")
    parser.add_argument(
        "--components", type=int, default=100, help="components for the threads (default 100)"
    )
    parser.add_argument(
        "--output",
        type=Path,
        default=RESULTS,
        help="where the figures go (default bench/results/container_hop.json)",
    )
    args = parser.parse_args()
    results = {
        "date": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
        "machine": f"{platform.machine()}, {platform.python_version()}, {os.cpu_count()} cores",
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "samples": args.samples,
        "gap_ms": args.gap_ms,
        "hops": hop_costs(args.samples, args.gap_ms),
        "add": add_latency(args.adds),
        "threads": threads(args.components),
        "targets": {"hop_us": 30, "figure6_over_direct": 1.25, "add_ms": 20},
    }
    write_results(args.output, results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
