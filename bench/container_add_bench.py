"""What an ``add`` costs as a container fills up while its components compute (issue 28, the
time from a query to its first sample: ``docs/performance.md``, "First sample for 100
applications, session 21").

A container (``services.container.Container``) runs in this process on a zenoh session
listening on loopback; a second process (``publish``, below) joins it and publishes
``--chains`` providers at ``--rate`` Hz, the static edges the chains read (each on a
``LatestValuePublisher``: asked for once) and subscribes to every chain's relation key, as an
application would. The container is given one chain at a time, ``--chains`` in all, each two
concatenations as in ``bench.container_hop_bench`` part 4 (the first reading its provider
over zenoh and a static edge, the second the first's output in the process and a static edge,
putting on an application's relation key: a hand-over watch), ``--gap`` seconds apart, so
every chain added computes at ``--rate`` Hz while the next ones are added, as 100
applications do in ``bench.containers_bench``. Timed: each ``add`` call (its check, the
components' construction and declarations, their start), per component, and grouped by how
many components the container held (20 at a time); with ``--profile``, the adds of the last
group under ``cProfile`` (the adding thread's calls, largest cumulative time first). With
``--declarations``, also what one zenoh declaration costs as a session holds more
(:func:`declaration_cost`): zenoh's own part of an add, which grows with the container.

Run::

    .venv/bin/python -m bench.container_add_bench [--chains 50] [--rate 10] [--gap 0.2] \\
        [--profile] [--declarations] [--output FILE]

Printed, and written to ``--output`` (default ``bench/results/container_add.json``). An add
that costs O(1) in the components the container holds shows as flat medians across the
groups; what grows beside it is the contention for Python's lock with the components
computing (their number times ``--rate``). Growth of the bench: O(chains).
"""

from __future__ import annotations

import argparse
import cProfile
import io
import os
import platform
import pstats
import statistics
import subprocess
import sys
import threading
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from bench.report import write_results
from ubitrack_agent.core import ErrorPose, encode
from ubitrack_agent.net import config
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.session import open_session
from ubitrack_agent.net.spec import ComponentSpec, InputBinding
from ubitrack_agent.net.transport import LatestValuePublisher, on_zenoh_thread
from ubitrack_agent.services.container import Container

RESULTS = Path(__file__).parent / "results"
GROUP = 20
"""Components per group of the figures (by how many the container held at the add)."""


def chain(keys: KeySpace, k: int) -> tuple[ComponentSpec, ComponentSpec]:
    """Chain ``k``: two concatenations, the first reading provider ``k`` and a static edge, the
    second the first's output and a static edge, putting on the relation key ``relation/<k>``
    (also ``bench.container_hop_bench`` part 4's)."""
    first = ComponentSpec(
        f"c{k}a",
        "concatenation",
        (
            InputBinding("AB", keys.data(f"static/{k}a"), static=True),
            InputBinding("BC", keys.data(f"provider/{k}"), trigger=True),
        ),
        {"AC": keys.data(f"c{k}a/out")},
    )
    second = ComponentSpec(
        f"c{k}b",
        "concatenation",
        (
            InputBinding("AB", keys.data(f"static/{k}b"), static=True),
            InputBinding("BC", keys.data(f"c{k}a/out"), trigger=True, from_worker=True),
        ),
        {"AC": keys.data(f"c{k}b/out")},
        relations={"AC": (keys.data(f"relation/{k}"),)},
    )
    return first, second


def publish(port: int, domain: str, chains: int, rate: float) -> None:
    """The other process: providers, static edges and the applications' subscribers, until
    killed."""
    keys = KeySpace(f"ubitrack/{domain}")
    settings = config.Settings(connect=(f"tcp/127.0.0.1:{port}",), domain=domain)
    covariance = np.eye(6) * 1e-6
    with open_session(settings) as session:
        static = encode(ErrorPose(time.time_ns(), [0, 0, 0, 1], [0.1, 0.2, 0.3], covariance))
        declared: list[Any] = []  # kept while the process runs
        for k in range(chains):
            for half in "ab":
                edge = LatestValuePublisher(session, keys.data(f"static/{k}{half}"), None)
                edge.put(static)
                declared.append(edge)
            application = session.declare_subscriber(
                keys.data(f"relation/{k}"), on_zenoh_thread(_ignore)
            )
            declared.append(application)
        providers = [session.declare_publisher(keys.data(f"provider/{k}")) for k in range(chains)]
        while True:
            now = time.time_ns()
            for provider in providers:
                provider.put(encode(ErrorPose(now, [0, 0, 0, 1], [1.0, 2.0, 3.0], covariance)))
            time.sleep(1.0 / rate)


def _ignore(sample: Any) -> None:
    """An application's subscriber: the sample arrived (zenoh carried it out of the
    container), nothing else."""


def measure(chains: int, rate: float, gap_s: float, profile: bool) -> dict[str, Any]:
    from tests.integration.zenoh_helpers import free_port

    port = free_port()
    domain = f"addbench{port}"
    keys = KeySpace(f"ubitrack/{domain}")
    settings = config.Settings(listen=(f"tcp/127.0.0.1:{port}",), domain=domain)
    profiler = cProfile.Profile()
    per_component: list[float] = []
    with open_session(settings) as session:
        command = [sys.executable, "-m", "bench.container_add_bench", "publish"]
        command += ["--port", str(port), "--domain", domain, "--chains", str(chains)]
        publisher = subprocess.Popen([*command, "--rate", str(rate)])
        container = Container(session, keys, "adds")
        runner = threading.Thread(target=container.run, daemon=True)
        runner.start()
        try:
            time.sleep(3.0)  # the publisher joined
            last_group = (2 * chains - 1) // GROUP * GROUP
            cpu_at = wall_at = None
            for k in range(chains):
                specs = chain(keys, k)
                timed = 2 * k >= last_group
                if timed and cpu_at is None:
                    cpu_at, wall_at = time.process_time(), time.monotonic()
                if timed and profile:
                    profiler.enable()
                start = time.perf_counter()
                container.add(specs)
                per_component.append((time.perf_counter() - start) * 1e3 / len(specs))
                if timed and profile:
                    profiler.disable()
                time.sleep(gap_s)
            cpu_s = time.process_time() - cpu_at
            busy = round(100 * cpu_s / (time.monotonic() - wall_at), 1)
            published = sum(e.worker.counters["published"] for e in container.components.values())
        finally:
            container.stop()
            runner.join(5.0)
            publisher.terminate()
            publisher.wait(10)
    groups = []
    for first in range(0, 2 * chains, GROUP):
        times = per_component[first // 2 : (first + GROUP) // 2]
        groups.append(
            {
                "components_held": f"{first}-{first + 2 * len(times)}",
                "add_ms_per_component_median": round(statistics.median(times), 2),
                "add_ms_per_component_max": round(max(times), 2),
            }
        )
    result: dict[str, Any] = {
        "groups": groups,
        "published_by_the_components": published,
        "process_cpu_percent_during_last_group": busy,
    }
    if profile:
        text = io.StringIO()
        pstats.Stats(profiler, stream=text).sort_stats("cumulative").print_stats(30)
        result["profile_last_group"] = text.getvalue().splitlines()
    return result


def declaration_cost(most: int = 500, step: int = 100, repeat: int = 20) -> list[dict[str, Any]]:
    """What zenoh's declarations cost as a session holds more: ``most`` publishers (each with
    a matching listener, as ``LatestValuePublisher`` declares), and every ``step`` of them
    ``repeat`` subscribers and ``repeat`` queryables declared, each timed (median us). One
    session, no peer, callbacks on zenoh's thread (no Python thread per declaration)."""
    rows = []
    with open_session(config.Settings(domain="declarations")) as session:
        held: list[Any] = []

        def timed(declare: Any, name: str) -> float:
            times = []
            for i in range(repeat):
                start = time.perf_counter()
                held.append(
                    declare(f"ubitrack/declarations/data/{name}{i}", on_zenoh_thread(_ignore))
                )
                times.append((time.perf_counter() - start) * 1e6)
            return round(statistics.median(times), 1)

        for n in range(most + 1):
            publisher = session.declare_publisher(f"ubitrack/declarations/data/p{n}/out")
            held += [publisher, publisher.declare_matching_listener(on_zenoh_thread(_ignore))]
            if n % step == 0:
                rows.append(
                    {
                        "publishers_held": n,
                        "subscriber_us": timed(session.declare_subscriber, f"s{n}x"),
                        "queryable_us": timed(session.declare_queryable, f"q{n}x"),
                    }
                )
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.container_add_bench", description=__doc__.split("\n\n")[0]
    )
    sub = parser.add_subparsers(dest="part")
    other = sub.add_parser("publish", help="the providers' process (started by the bench)")
    other.add_argument("--port", type=int, required=True)
    other.add_argument("--domain", required=True)
    other.add_argument("--chains", type=int, required=True)
    other.add_argument("--rate", type=float, required=True)
    parser.add_argument("--chains", type=int, default=50, help="two components each")
    parser.add_argument("--rate", type=float, default=10.0, help="Hz per provider")
    parser.add_argument("--gap", type=float, default=0.2, help="s between two adds")
    parser.add_argument("--profile", action="store_true", help="cProfile the last group")
    parser.add_argument(
        "--declarations", action="store_true", help="also zenoh's declaration cost by size"
    )
    parser.add_argument("--output", type=Path, default=RESULTS / "container_add.json")
    args = parser.parse_args(argv)
    if args.part == "publish":
        publish(args.port, args.domain, args.chains, args.rate)
        return 0
    load_at_start = os.getloadavg()
    result = measure(args.chains, args.rate, args.gap, args.profile)
    if args.declarations:
        result["zenoh_declarations"] = declaration_cost()
    write_results(
        args.output,
        {
            "command": "python -m bench.container_add_bench " + " ".join(argv or sys.argv[1:]),
            "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
            "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
            "load_average_at_start": [round(x, 2) for x in load_at_start],
            "load_average_at_end": [round(x, 2) for x in os.getloadavg()],
            **result,
        },
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
