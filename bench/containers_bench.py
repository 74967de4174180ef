"""Many applications on one host with containers (issue 28, "Done when"): the memory of the
host's worker processes, their number, the machine's load and each application's time to its
first sample while applications are added one by one.

Everything on loopback with real zenoh and real processes: an agent with its host manager
(``--pool-size``, default 2; one container per core of the machine, ``ubitrack host --cores``),
``--trackers`` providers (each a tracker ``T<k>`` in room ``R`` seeing bodies ``H<k>_1``,
``H<k>_2`` at ``--rate`` Hz, all published by one process: ``bench.agent_live_bench publish``),
the static ``R -> T<k>`` of each, and, once the host manager's warm pool is full (a
container's cold start is measured apart), applications (``io.application.Relation``) added
one every ``--every`` seconds, up to ``--applications`` or until the machine has less than 3 GB of
memory available. ``--relations per-tracker``: five relations per tracker
(``bench.agent_live_bench.relations_of``: about one component each); ``cross``: a body of one
tracker seen from a body of another, ``H<k>_1 -> H<k+d>_2`` for d = 1, 2, ... (through the
room: an inversion, a composition with the static edges, about three components each, some
shared).

After each application: the components the agent wants and those alive, the worker processes
(the host manager's children running ``ubitrack_agent.services.worker``: containers and idle pool
members) and their memory, as the unique set size (USS: private clean and dirty pages, from
``/proc/<pid>/smaps_rollup``) summed over them, and the machine's one-minute load average.
At the end: each application's time from its query to its first sample (median, 90th
percentile, largest), broken into its parts (:func:`first_sample_parts`, from the stamps the
agent and the components take where each step happens: ``agent.stamps``, a component's
``stamps`` in its status), and the CPU each part used over ``CPU_S`` (percent of one core: the
worker processes, the agent, its host manager, the publishing process). Run::

    .venv/bin/python -m bench.containers_bench [--applications 100] [--trackers 20] \\
        [--rate 10] [--every 1.0] [--pool-size 2] [--relations cross|per-tracker] [--output FILE]

Printed, and written to ``--output`` (default ``bench/results/containers_<relations>.json``).
Growth: the bench's own work is O(applications x worker processes) reads of ``/proc``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from bench.agent_live_bench import (
    Hub,
    add_rooms,
    available_bytes,
    close_all,
    open_application,
    relations_of,
    start_publisher,
)
from bench.cpu_use import _stat
from ubitrack_agent.agent.flows import plan_name
from ubitrack_agent.io.application import Relation
from ubitrack_agent.net.host_protocol import Status, encode_request
from ubitrack_agent.net.keys import RelationId
from ubitrack_agent.net.transport import fetch_latest

RESULTS = Path(__file__).parent / "results"
CPU_S = 10.0
"""Seconds over which the CPU of each part is measured at the end."""
MIN_AVAILABLE_BYTES = 3 << 30
"""Applications stop being added when the machine has less memory available than this."""


def children(pid: int) -> list[int]:
    """Every descendant of process ``pid`` (from ``/proc/<pid>/task/*/children``)."""
    found, todo = [], [pid]
    while todo:
        parent = todo.pop()
        try:
            tasks = os.listdir(f"/proc/{parent}/task")
        except OSError:
            continue
        for task in tasks:
            try:
                with open(f"/proc/{parent}/task/{task}/children", encoding="ascii") as file:
                    kids = [int(text) for text in file.read().split()]
            except OSError:
                continue
            found += kids
            todo += kids
    return found


def command_line(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as file:
            return file.read().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def uss_bytes(pid: int) -> int:
    """The unique set size of ``pid``: its private pages, clean and dirty (0 if gone)."""
    total = 0
    try:
        with open(f"/proc/{pid}/smaps_rollup", encoding="ascii") as file:
            for line in file:
                if line.startswith(("Private_Clean:", "Private_Dirty:")):
                    total += int(line.split()[1]) * 1024
    except OSError:
        return 0
    return total


def worker_processes(agent_pid: int) -> list[int]:
    """The worker processes (containers, pool members) under the agent's host manager."""
    return [
        pid for pid in children(agent_pid) if "ubitrack_agent.services.worker" in command_line(pid)
    ]


def run(args: argparse.Namespace) -> dict[str, Any]:
    hub = Hub(None, "--pool-size", str(args.pool_size))
    publisher = room = None
    opened: list[Relation] = []
    first: dict[str, int] = {}
    asked: dict[str, int] = {}
    """When each application asked and got its first sample (``time.time_ns``: the clock
    the agent's and the components' stamps use)."""
    asking: dict[str, RelationId] = {}
    seen: dict[str, dict[str, Any]] = {}
    """The agent's status ``--every`` seconds after each application asked (its stamps then:
    a component's latest start or rewire may be a later application's at the end)."""
    rows: list[dict[str, Any]] = []
    try:
        publisher = start_publisher(hub, args.trackers, args.rate)
        room = add_rooms(hub, args.trackers)
        relations = (cross_relations if args.relations == "cross" else relations_of)(args.trackers)
        warm_s = warm_pool(hub, args.pool_size)
        print(f"  warm pool of {args.pool_size} after {warm_s:.1f} s", flush=True)
        for n, relation in enumerate(relations[: args.applications], 1):
            if available_bytes() < MIN_AVAILABLE_BYTES:
                print(f"  stopping at {n - 1} applications: memory", flush=True)
                break
            asking[f"app{n}"] = relation
            opened.append(
                open_application(hub, relation, f"app{n}", asked, first, clock=time.time_ns)
            )
            time.sleep(args.every)
            seen[f"app{n}"] = hub.status() or {}
            rows.append(measure(hub, n, len(first), seen[f"app{n}"]))
            r = rows[-1]
            print(
                f"  {n:3d} applications ({r['with_data']} with data): {r['components']} "
                f"components, {r['alive']} alive, in {r['containers']} containers; "
                f"{r['worker_processes']} worker processes, {r['uss_mb']:.0f} MB; "
                f"load {r['load_1min']:.2f}",
                flush=True,
            )
        deadline = time.monotonic() + args.settle
        while len(first) < len(asked) and time.monotonic() < deadline:
            time.sleep(0.2)
        final = measure(hub, len(asked), len(first), hub.status() or {})
        breakdown = first_sample_parts(hub, asking, asked, first, seen)
        final["cpu_percent"] = cpu_percent(hub, publisher.pid, CPU_S)
    finally:
        close_all(opened, room, publisher, hub)
    to_first = sorted((first[name] - asked[name]) / 1e9 for name in first)
    return {
        "applications": len(asked),
        "trackers": args.trackers,
        "rate_hz": args.rate,
        "pool_size": args.pool_size,
        "relations": args.relations,
        "rows": rows,
        "final": final,
        "first_sample_median_s": round(statistics.median(to_first), 3) if to_first else None,
        "first_sample_p90_s": round(to_first[int(0.9 * (len(to_first) - 1))], 3)
        if to_first
        else None,
        "first_sample_max_s": round(to_first[-1], 3) if to_first else None,
        "applications_without_data": len(asked) - len(first),
        "first_sample_parts": breakdown,
    }


def warm_pool(hub: Hub, pool_size: int, timeout: float = 120.0) -> float:
    """Wait until the host manager's warm pool is full (the steady state the figures are
    for: a container's cold start is measured apart, ``bench/worker_start.py``); how long it
    took from here (s)."""
    started = time.monotonic()

    def full() -> bool:
        hosts = (hub.status() or {}).get("hosts", [])
        if len(hosts) != 1:
            return False
        key = hub.keys.host_request(hosts[0])
        replies = list(hub.session.get(key, payload=encode_request(Status()), timeout=1.0))
        ok = [json.loads(r.ok.payload.to_bytes()) for r in replies if r.ok is not None]
        return bool(ok) and ok[0]["pool_ready"] >= pool_size

    while not full():
        if time.monotonic() - started > timeout:
            raise RuntimeError(f"the warm pool not full within {timeout} s")
        time.sleep(0.2)
    return time.monotonic() - started


PATHS = {
    "started": (
        ("to the agent", "received_ns"),
        ("agent's loop takes it", "handled_ns"),
        ("waits for the planning thread", "plan_asked_ns"),
        ("planning", "plan_made_ns"),
        ("plan applied on the loop", "planned_ns"),
        ("to the start request", "requested_ns"),
        ("host manager and container add it", "created_ns"),
        ("component declares its keys", "ready_ns"),
        ("its inputs' first samples", "inputs_ns"),
        ("computed down the chain to the application's key", "published_ns"),
        ("to the application", "first_ns"),
    ),
    "rewired": (
        ("to the agent", "received_ns"),
        ("agent's loop takes it", "handled_ns"),
        ("waits for the planning thread", "plan_asked_ns"),
        ("planning", "plan_made_ns"),
        ("plan applied on the loop", "planned_ns"),
        ("to the rewire command", "rewired_ns"),
        ("producer's next output on the application's key", "published_ns"),
        ("to the application", "first_ns"),
    ),
}
"""The steps from an application's query to its first sample, in order, each with the stamp
that ends it (``asked_ns`` begins the first): through a component started for it, or through
running components rewired to publish on its key."""


def first_sample_parts(
    hub: Hub,
    asking: dict[str, RelationId],
    asked: dict[str, int],
    first: dict[str, int],
    seen: dict[str, dict[str, Any]],
) -> dict[str, Any]:
    """Each application's time to its first sample cut into the parts of :data:`PATHS`,
    from the stamps taken where each step happened (the agent's status, every component's
    status): per part the median, 90th percentile and largest (ms) over the applications with
    data.

    The path of an application: the component publishing its relation key (its *producer*),
    then, while the input of the component at hand whose first sample came last came after
    the query and another component created after the query produces it, that component; the
    last one is the *root*. If the root was created after the query, the path is ``started``
    (the root's start request, creation, ... its first inputs, then the producer's first
    output on the key), else ``rewired``. Parts are differences of consecutive stamps, so
    they add up to the whole (a negative part: a step done before the one listed first, say
    a component started for an earlier application).

    The agent's stamps and components are those of its status taken after each application
    asked (``seen``; one whose producer was not planned yet takes the status at the end), the
    components' those of their statuses at the end (each stamps a step the first time).
    O(applications x path length x inputs)."""
    final = hub.status(timeout=5.0) or {}
    workers: dict[str, dict[str, Any]] = {}
    for payload in fetch_latest(hub.session, hub.keys.all_statuses(), timeout=5.0):
        answer = json.loads(payload)
        if "instance" in answer:
            workers[answer["instance"]] = answer

    by_path: dict[str, list[dict[str, int]]] = {"started": [], "rewired": []}
    missing: dict[str, str] = {}
    """Applications with data left out, with why (their steps cannot be told apart)."""
    each: list[dict[str, Any]] = []
    for name, relation in asking.items():
        if name not in first:
            continue
        key = hub.keys.relation(relation)
        status = seen.get(name, {})
        producer_of = _producers(status.get("components", {}))
        if key not in producer_of:
            status = final
            producer_of = _producers(status.get("components", {}))
        components, agent_stamps = status.get("components", {}), status.get("stamps", {})
        query = agent_stamps.get("queries", {}).get(plan_name(relation), {}).get(name, {})
        producer = producer_of.get(key)
        stamps = workers.get(producer, {}).get("stamps") if producer else None
        if not query or stamps is None or key not in stamps["first_published_ns"]:
            missing[name] = "no stamps (the agent's, or its producer's on the key)"
            continue
        root, root_stamps = producer, stamps
        visited = {producer}
        while True:
            firsts = root_stamps["first_sample_ns"]
            inputs = [b["key"] for b in components[root]["inputs"]]
            latest = max(inputs, key=lambda k: firsts.get(k, 0), default=None)
            upstream = producer_of.get(latest) if latest else None
            if (
                upstream is None
                or upstream in visited
                or firsts.get(latest, 0) < asked[name]
                or upstream not in workers
                or workers[upstream]["stamps"]["created_ns"] < asked[name]
            ):
                break
            root, root_stamps = upstream, workers[upstream]["stamps"]
            visited.add(root)
        path = "started" if root_stamps["created_ns"] > asked[name] else "rewired"
        firsts = root_stamps["first_sample_ns"]
        agent_component = agent_stamps.get("components", {})
        times = {
            "asked_ns": asked[name],
            **query,
            **agent_component.get(root, {}),
            "rewired_ns": agent_component.get(producer, {}).get("rewired_ns", 0),
            "created_ns": root_stamps["created_ns"],
            "ready_ns": root_stamps["ready_ns"],
            "inputs_ns": max(
                (firsts.get(b["key"], 0) for b in components[root]["inputs"]), default=0
            ),
            "published_ns": stamps["first_published_ns"][key],
            "first_ns": first[name],
        }
        steps = PATHS[path]
        if any(times.get(stamp, 0) == 0 for _, stamp in steps):
            missing[name] = "a step not stamped"
            continue
        if any(times[stamp] > first[name] for _, stamp in steps[:-2]):
            # The query seen again (its token lost and declared again) or the component
            # started again after the first sample: the stamps are of a later round.
            missing[name] = "stamped after its first sample"
            continue
        previous = times["asked_ns"]
        parts = {}
        for part, stamp in steps:
            parts[part] = times[stamp] - previous
            previous = times[stamp]
        by_path[path].append({**parts, "total": times["first_ns"] - times["asked_ns"]})
        each.append(
            {
                "application": name,
                "path": path,
                "producer": producer,
                "root": root,
                **{part: round(ms / 1e6, 1) for part, ms in parts.items()},
            }
        )
    return {
        path: {"applications": len(rows), **_part_figures(rows, [p for p, _ in PATHS[path]])}
        for path, rows in by_path.items()
    } | {"left_out": dict(sorted(missing.items())), "each_ms": each}


def _producers(components: dict[str, Any]) -> dict[str, str]:
    """The component producing each data and relation key, from the agent's ``components``."""
    return {
        key: instance
        for instance, spec in components.items()
        for keys in (spec["outputs"].values(), *spec["relations"].values())
        for key in keys
    }


def print_parts(breakdown: dict[str, Any]) -> None:
    """The parts of the time to a first sample, one line each (:func:`first_sample_parts`)."""
    for path in PATHS:
        figures = breakdown[path]
        print(f"first sample through a component {path}: {figures['applications']} applications")
        for part, values in figures.items():
            if part != "applications":
                print(
                    f"  {part:52s} median {values['median_ms']:7.1f} ms, "
                    f"p90 {values['p90_ms']:7.1f}, max {values['max_ms']:7.1f}"
                )


def _part_figures(rows: list[dict[str, int]], parts: list[str]) -> dict[str, Any]:
    """Median, 90th percentile and largest of each part and the total (ms)."""
    figures = {}
    for part in [*parts, "total"]:
        values = sorted(row[part] / 1e6 for row in rows)
        if values:
            figures[part] = {
                "median_ms": round(statistics.median(values), 1),
                "p90_ms": round(values[int(0.9 * (len(values) - 1))], 1),
                "max_ms": round(values[-1], 1),
            }
    return figures


def cpu_percent(hub: Hub, publisher: int, seconds: float) -> dict[str, float]:
    """Percent of one core each part used over ``seconds``: the worker processes (containers
    and pool members), the agent, its host manager, the publishing process."""
    host = [
        pid
        for pid in children(hub.agent.pid)
        if "ubitrack_agent.services.host" in command_line(pid)
    ]
    parts = {
        "workers": worker_processes(hub.agent.pid),
        "agent": [hub.agent.pid],
        "host_manager": host,
        "publisher": [publisher],
    }

    def ticks() -> dict[str, int]:
        return {
            name: sum(stat[1] for pid in pids if (stat := _stat(pid)) is not None)
            for name, pids in parts.items()
        }

    before, started = ticks(), time.monotonic()
    time.sleep(seconds)
    after, took = ticks(), time.monotonic() - started
    per_s = os.sysconf("SC_CLK_TCK") * took
    return {name: round(100.0 * (after[name] - before[name]) / per_s, 1) for name in parts}


def cross_relations(trackers: int) -> list[RelationId]:
    """``H<k>_1 -> H<k+d>_2`` for d = 1, 2, ... and each k (module docstring)."""
    return [
        RelationId(f"H{k}_1", f"H{(k + d) % trackers}_2", "6D")
        for d in range(1, trackers)
        for k in range(trackers)
    ]


def measure(hub: Hub, applications: int, with_data: int, status: dict[str, Any]) -> dict[str, Any]:
    """The agent's components (from its ``status``), the host's worker processes and their
    memory, the load."""
    components = status.get("components", {})
    workers = worker_processes(hub.agent.pid)
    return {
        "applications": applications,
        "with_data": with_data,
        "components": len(components),
        "alive": sum(c["alive"] for c in components.values()),
        "containers": len({c.get("container") for c in components.values()} - {None}),
        "worker_processes": len(workers),
        "uss_mb": round(sum(uss_bytes(pid) for pid in workers) / 2**20, 1),
        "load_1min": os.getloadavg()[0],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.containers_bench", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--applications", type=int, default=100)
    parser.add_argument("--trackers", type=int, default=20, help="five relations each")
    parser.add_argument("--rate", type=float, default=10.0, help="Hz per tracked body")
    parser.add_argument("--every", type=float, default=1.0, help="s between applications")
    parser.add_argument("--pool-size", type=int, default=2)
    parser.add_argument("--relations", choices=("per-tracker", "cross"), default="cross")
    parser.add_argument(
        "--settle", type=float, default=20.0, help="s to wait at the end for first samples"
    )
    parser.add_argument(
        "--output", type=Path, help="where to write the figures (default: by --relations)"
    )
    args = parser.parse_args(argv)
    result = run(args)
    results = {
        "command": "python -m bench.containers_bench " + " ".join(argv or sys.argv[1:]),
        "date": datetime.now(UTC).strftime("%Y-%m-%d"),
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "load_1min_at_start": result["rows"][0]["load_1min"] if result["rows"] else None,
        },
        **result,
    }
    RESULTS.mkdir(exist_ok=True)
    written = args.output or RESULTS / f"containers_{args.relations.replace('-', '_')}.json"
    written.write_text(json.dumps(results, indent=2) + "\n")
    print_parts(result["first_sample_parts"])
    shown = {k: v for k, v in results.items() if k not in ("rows", "first_sample_parts")}
    print(json.dumps(shown, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
