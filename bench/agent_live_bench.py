"""The live agent on one host (issue [scale]): its CPU against the sensors' sample rate, and how
fast it answers its status while applications keep coming.

Everything on loopback with real zenoh and real processes. Two parts:

* ``cpu``: the agent alone (``ubitrack agent --no-host``, no query, so no worker: *idle, no
  provider*), then with 20 providers x 10 dynamic 6D edges (``io.provider.Provider``, all in
  one publishing process, ``python -m bench.agent_live_bench publish``) announced but not
  publishing (rate 0: *idle, providers announced*; their edges go quiet, and each provider
  reports so every second) and publishing at 1, 10 and 50 Hz (``--rates``): the agent's CPU (its
  process's ``utime + stime`` from ``/proc``, ``bench.cpu_use``) over ``--seconds``, in percent
  of one core, beside the samples per second actually published and the ratio to each idle
  figure. ``--compare CHECKOUT``
  measures the same with the agent of another checkout (run in its directory, so ``-m`` imports
  its code; by its ``.venv`` if it has one: e.g. ``git archive`` of the commit before the agent
  left the data path) in the same run, side by side.
* ``status``: the agent with its host manager (``--pool-size 2``) and 10 providers (each a
  tracker ``T<k>`` in room ``R`` seeing bodies ``H<k>_1``, ``H<k>_2`` at 10 Hz); applications
  (``io.application.Relation``) are added one every ``--every`` seconds, five relations per
  tracker (``H->T`` twice, ``R->H`` twice, ``H<k>_1->H<k>_2``), up to ``--applications`` (50)
  or until the machine has less than 3 GB of memory available. Throughout, the bench asks the
  agent's status every 50 ms (``<root>/agent/status``), from a process of its own
  (``probe``), and records each answer's latency, and beside it that of a control: a process
  that does nothing but answer 20 kB on a key of its own (``echo``), so that what the machine's
  load costs every process is told from what the agent adds. Per window (one application
  added): the medians and maxima of both, the load average, the agent's CPU, its slowest loop
  pass and handler (its status's ``loop``), its plan times and replanning counters; at the
  end each application's time to its first sample.

Run::

    .venv/bin/python -m bench.agent_live_bench                  # both parts
    .venv/bin/python -m bench.agent_live_bench --part cpu --compare ../before   # a checkout

Printed, and written to ``bench/results/agent_live.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import statistics
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from bench.cpu_use import _stat
from tests.integration.conftest import kill_tagged
from tests.integration.zenoh_helpers import free_port, wait_until
from ubitrack_agent.core import ErrorPose
from ubitrack_agent.io.application import Relation
from ubitrack_agent.io.provider import EdgeAnnouncement, Provider
from ubitrack_agent.net import config
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.session import open_session
from ubitrack_agent.net.transport import fetch_latest

RESULTS = Path(__file__).parent / "results" / "agent_live.json"
TICKS_PER_S = os.sysconf("SC_CLK_TCK")
MIN_AVAILABLE_BYTES = 3 << 30
"""Applications stop being added when the machine has less memory available than this."""


# -- the publishing process -------------------------------------------------------------------


def publish(args: argparse.Namespace) -> int:
    """Announce ``--providers`` providers of ``--edges`` dynamic edges each and publish them
    all at ``--rate`` Hz until SIGTERM; print the samples published per second."""
    settings = settings_of(args)
    keys = KeySpace(settings.key_prefix)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    pose = (np.array([1.0, 0, 0, 0]), np.zeros(3), np.eye(6) * 1e-6)
    with open_session(settings) as session:
        providers = [
            Provider(
                session,
                keys,
                f"p{k}",
                [
                    EdgeAnnouncement(f"T{k}", f"H{k}_{j}", "6D", rate=args.rate or 10.0)
                    for j in range(1, args.edges + 1)
                ],
            )
            for k in range(args.providers)
        ]
        names = [(p, name) for p in providers for name in p.edges]
        published, started = 0, time.monotonic()
        tick = started
        while args.rate > 0 and not stop.is_set():
            stamp = time.time_ns()
            for provider, name in names:
                provider.publish(name, ErrorPose(stamp, *pose))
            published += len(names)
            tick += 1.0 / args.rate
            stop.wait(max(0.0, tick - time.monotonic()))
        stop.wait()
        seconds = time.monotonic() - started
        for provider in providers:
            provider.close()
    print(json.dumps({"samples_per_s": published / seconds}), flush=True)
    return 0


def settings_of(args: argparse.Namespace) -> config.Settings:
    return config.Settings(
        connect=(f"tcp/127.0.0.1:{args.port}",), listen=("tcp/127.0.0.1:0",), domain=args.domain
    )


def echo(args: argparse.Namespace) -> int:
    """Answer queries on the control key (``echo_key``) with ``--bytes`` of JSON until SIGTERM:
    a queryable in a process of its own that does nothing else, beside the agent's status."""
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    settings = settings_of(args)
    answer = json.dumps({"padding": "x" * args.bytes})
    key = echo_key(KeySpace(settings.key_prefix))
    with open_session(settings) as session:
        queryable = session.declare_queryable(key, lambda query: query.reply(key, answer))
        stop.wait()
        queryable.undeclare()
    return 0


def echo_key(keys: KeySpace) -> str:
    return f"{keys.root}/bench/echo"


def probe(args: argparse.Namespace) -> int:
    """Every ``--period`` s ask the agent's status, then the echo process (the control), each
    answer's latency printed as a JSON line ``{"key", "t", "s"}`` (``t``: the monotonic clock,
    shared by the processes of the machine; ``s``: null when unanswered), until SIGTERM."""
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    settings = settings_of(args)
    keys = KeySpace(settings.key_prefix)
    targets = {"status": keys.agent_status(), "echo": echo_key(keys)}
    with open_session(settings) as session:
        while not stop.wait(args.period):
            for name, key in targets.items():
                started = time.monotonic()
                answered = fetch_latest(session, key, timeout=5.0)
                seconds = time.monotonic() - started if answered else None
                loop = (
                    json.loads(answered[0]).get("loop") if answered and name == "status" else None
                )
                print(
                    json.dumps({"key": name, "t": started, "s": seconds, "loop": loop}), flush=True
                )
    return 0


# -- helpers ----------------------------------------------------------------------------------


class Hub:
    """An agent on a fresh port and domain, and a session of the bench on it."""

    def __init__(self, checkout: Path | None, *agent_options: str) -> None:
        own = checkout / ".venv" / "bin" / "python" if checkout else None
        python = str(own) if own and own.exists() else sys.executable
        self.port = free_port()
        self.domain = f"live{self.port}"
        self.agent = subprocess.Popen(
            [
                python,
                "-m",
                "ubitrack_agent.cli",
                "--log-level",
                "ERROR",
                "agent",
                "--quiet",
                "--listen",
                f"tcp/127.0.0.1:{self.port}",
                "--domain",
                self.domain,
                *agent_options,
            ],
            start_new_session=True,
            cwd=checkout,  # its own package, not this one's (``-m`` puts the cwd first)
        )
        settings = config.Settings(
            connect=(f"tcp/127.0.0.1:{self.port}",), listen=("tcp/127.0.0.1:0",), domain=self.domain
        )
        self.keys = KeySpace(settings.key_prefix)
        self.session = open_session(settings)
        wait_until(lambda: self.status() is not None, timeout=30)

    def status(self, timeout: float = 2.0) -> dict | None:
        replies = fetch_latest(self.session, self.keys.agent_status(), timeout=timeout)
        return json.loads(replies[0]) if replies else None

    def agent_cpu_s(self) -> float:
        stat = _stat(self.agent.pid)
        return stat[1] / TICKS_PER_S if stat else float("nan")

    def close(self) -> None:
        self.session.close()
        self.agent.send_signal(signal.SIGTERM)
        try:
            self.agent.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.agent.kill()
        kill_tagged(self.domain)


def agent_cpu(hub: Hub, seconds: float) -> float:
    """The agent's CPU over ``seconds``, in percent of one core."""
    before, started = hub.agent_cpu_s(), time.monotonic()
    time.sleep(seconds)
    return 100.0 * (hub.agent_cpu_s() - before) / (time.monotonic() - started)


# -- the CPU part -----------------------------------------------------------------------------


def cpu_part(
    checkout: Path | None, rates: list[float], seconds: float, providers: int, edges: int
) -> dict:
    hub = Hub(checkout, "--no-host")
    name = str(checkout or "this checkout")
    rows = []
    try:
        time.sleep(3.0)  # start-up settled
        rows.append(
            {
                "rate_hz": None,
                "samples_per_s": 0.0,
                "agent_cpu_pct": agent_cpu(hub, seconds),
                "stale": 0,
            }
        )
        print(f"  {name}: idle, no provider: agent {rows[0]['agent_cpu_pct']:5.2f} % of a core")
        for rate in rates:
            publisher = subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "bench.agent_live_bench",
                    "publish",
                    "--rate",
                    str(rate),
                    "--providers",
                    str(providers),
                    "--edges",
                    str(edges),
                    "--port",
                    str(hub.port),
                    "--domain",
                    hub.domain,
                ],
                stdout=subprocess.PIPE,
                text=True,
                start_new_session=True,
            )
            try:
                wait_until(lambda: len((hub.status() or {}).get("providers", ())) == providers, 60)
                time.sleep(3.0)
                cpu = agent_cpu(hub, seconds)
                stale = len((hub.status() or {}).get("stale_edges", ()))
            finally:
                publisher.send_signal(signal.SIGTERM)
                out, _ = publisher.communicate(timeout=60)
            rate_out = json.loads(out.strip().splitlines()[-1])["samples_per_s"]
            rows.append(
                {"rate_hz": rate, "samples_per_s": rate_out, "agent_cpu_pct": cpu, "stale": stale}
            )
            print(
                f"  {name}: {rate:5.1f} Hz, {rate_out:8.0f} samples/s published: "
                f"agent {cpu:5.2f} % of a core ({stale} stale edges)",
                flush=True,
            )
            wait_until(lambda: not (hub.status() or {}).get("providers"), 30)
    finally:
        hub.close()
    idle = rows[0]["agent_cpu_pct"]
    announced = next((r["agent_cpu_pct"] for r in rows if r["rate_hz"] == 0), None)
    for row in rows[1:]:
        row["of_idle"] = row["agent_cpu_pct"] / idle if idle else None
        row["of_announced"] = row["agent_cpu_pct"] / announced if announced else None
        print(
            f"  {name}: {row['rate_hz']:5.1f} Hz: {row['of_idle'] or 0:.2f} x idle without "
            f"providers, {row['of_announced'] or 0:.2f} x idle with them announced"
        )
    return {"agent": name, "rows": rows, "load_average": os.getloadavg()[0]}


# -- the status part --------------------------------------------------------------------------


def relations_of(trackers: int) -> list[RelationId]:
    """Five relations per tracker (module docstring), taken round-robin over the trackers."""
    per = [
        lambda k: RelationId(f"H{k}_1", f"T{k}", "6D"),
        lambda k: RelationId("R", f"H{k}_1", "6D"),
        lambda k: RelationId(f"H{k}_2", f"T{k}", "6D"),
        lambda k: RelationId("R", f"H{k}_2", "6D"),
        lambda k: RelationId(f"H{k}_1", f"H{k}_2", "6D"),
    ]
    return [make(k) for make in per for k in range(trackers)]


def available_bytes() -> int:
    with open("/proc/meminfo") as file:
        for line in file:
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    return 0


class StatusProbe:
    """The probing process (``probe``: the agent's status and the control queryable every
    ``period`` s, from a process of its own, so the bench's applications do not delay it) and
    the echo process; keeps each key's (time, latency) pairs as they come."""

    def __init__(self, hub: Hub, period: float = 0.05) -> None:
        self.samples: dict[str, list[tuple[float, float]]] = {"status": [], "echo": []}
        self.unanswered: dict[str, int] = {"status": 0, "echo": 0}
        self.loops: list[tuple[float, dict[str, Any]]] = []
        where = ["--port", str(hub.port), "--domain", hub.domain]
        self._echo = subprocess.Popen(
            [sys.executable, "-m", "bench.agent_live_bench", "echo", "--bytes", "20000", *where],
            start_new_session=True,
        )
        self._probe = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "bench.agent_live_bench",
                "probe",
                "--period",
                str(period),
                *where,
            ],
            stdout=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        assert self._probe.stdout is not None
        for line in self._probe.stdout:
            sample = json.loads(line)
            if sample["s"] is None:
                self.unanswered[sample["key"]] += 1
            else:
                self.samples[sample["key"]].append((sample["t"], sample["s"]))
            if sample["loop"]:
                self.loops.append((sample["t"], sample["loop"]))

    def slowest_pass(self, start: float) -> dict[str, Any]:
        """The agent's slowest loop pass seen since ``start`` (its status's ``loop``)."""
        seen = [loop for t, loop in self.loops if t >= start]
        return max(seen, key=lambda loop: loop["slowest_pass_s"], default={})

    def window(self, key: str, start: float) -> list[float]:
        return [lat for t, lat in self.samples[key] if t >= start]

    def stop(self) -> None:
        for process in (self._probe, self._echo):
            process.send_signal(signal.SIGTERM)
            try:
                process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                process.kill()
        self._thread.join(timeout=10)


def status_part(applications: int, every: float, trackers: int, rate: float) -> dict:
    hub = Hub(None, "--pool-size", "2")
    publisher = room = probe = None
    opened: list[Relation] = []
    first: dict[str, float] = {}
    asked: dict[str, float] = {}
    rows = []
    try:
        publisher = start_publisher(hub, trackers, rate)
        room = add_rooms(hub, trackers)
        probe = StatusProbe(hub)
        for n, relation in enumerate(relations_of(trackers)[:applications], 1):
            if available_bytes() < MIN_AVAILABLE_BYTES:
                print(f"  stopping at {n - 1} applications: memory", flush=True)
                break
            opened.append(open_application(hub, relation, f"app{n}", asked, first))
            window_start, cpu_before = time.monotonic(), hub.agent_cpu_s()
            time.sleep(every)
            cpu = (hub.agent_cpu_s() - cpu_before) / (time.monotonic() - window_start)
            latencies = probe.window("status", window_start)
            control = probe.window("echo", window_start)
            status = hub.status() or {}
            loop = probe.slowest_pass(window_start)
            rows.append(
                {
                    "applications": n,
                    "status_median_s": statistics.median(latencies) if latencies else None,
                    "status_max_s": max(latencies) if latencies else None,
                    "echo_median_s": statistics.median(control) if control else None,
                    "echo_max_s": max(control) if control else None,
                    "load_average": os.getloadavg()[0],
                    "agent_cpu_pct": 100.0 * cpu,
                    "slowest_pass_s": loop.get("slowest_pass_s"),
                    "slowest_handler": loop.get("slowest_handler"),
                    "slowest_handler_s": loop.get("slowest_handler_s"),
                    "workers_alive": sum(c["alive"] for c in status.get("components", {}).values()),
                    "last_plan_s": status.get("planning", {}).get("last_plan_s"),
                    **{
                        name: status.get("counters", {}).get(name, 0)
                        for name in ("replans", "relations_replanned", "plans_memoised")
                    },
                }
            )
            r = rows[-1]
            print(
                f"  {n:3d} applications: status median {1e3 * (r['status_median_s'] or 0):6.1f} ms"
                f" max {1e3 * (r['status_max_s'] or 0):7.1f} ms (echo "
                f"{1e3 * (r['echo_median_s'] or 0):.1f}/{1e3 * (r['echo_max_s'] or 0):.1f} ms); "
                f"load {r['load_average']:.1f}, agent {r['agent_cpu_pct']:.0f} % of a core; "
                f"slowest pass {1e3 * (r['slowest_pass_s'] or 0):.0f} ms "
                f"({r['slowest_handler']} {1e3 * (r['slowest_handler_s'] or 0):.0f} ms); "
                f"{r['workers_alive']} workers "
                f"alive; last plan {1e3 * (r['last_plan_s'] or 0):.1f} ms; {r['replans']} replans, "
                f"{r['relations_replanned']} relations replanned ({r['plans_memoised']} from "
                "the memo)",
                flush=True,
            )
        time.sleep(5.0)
    finally:
        if probe is not None:
            probe.stop()
        close_all(opened, room, publisher, hub)
    latencies = [lat for _, lat in probe.samples["status"]]
    control = [lat for _, lat in probe.samples["echo"]]
    to_first = [first[name] - asked[name] for name in first]
    return {
        "trackers": trackers,
        "rate_hz": rate,
        "rows": rows,
        "status_median_s": statistics.median(latencies),
        "status_max_s": max(latencies),
        "status_answers": len(latencies),
        "status_unanswered": probe.unanswered["status"],
        "echo_median_s": statistics.median(control),
        "echo_max_s": max(control),
        "echo_unanswered": probe.unanswered["echo"],
        "first_sample_median_s": statistics.median(to_first) if to_first else None,
        "first_sample_max_s": max(to_first) if to_first else None,
        "applications_without_data": len(asked) - len(first),
    }


def start_publisher(hub: Hub, trackers: int, rate: float) -> subprocess.Popen:
    """The process publishing ``trackers`` trackers' two bodies at ``rate`` Hz (``publish``),
    once the agent has their fragments."""
    edges = [
        sys.executable, "-m", "bench.agent_live_bench", "publish", "--rate", str(rate),
        "--providers", str(trackers), "--edges", "2", "--port", str(hub.port),
        "--domain", hub.domain,
    ]  # fmt: skip
    publisher = subprocess.Popen(edges, stdout=subprocess.DEVNULL, start_new_session=True)
    wait_until(lambda: len((hub.status() or {}).get("providers", ())) == trackers, 60)
    return publisher


def close_all(
    opened: list[Relation], room: Provider | None, publisher: subprocess.Popen | None, hub: Hub
) -> None:
    """End a run: the applications, the rooms' provider, the publisher process, the hub."""
    for relation in opened:
        relation.close()
    if room is not None:
        room.close()
    if publisher is not None:
        publisher.send_signal(signal.SIGTERM)
        publisher.wait(timeout=60)
    hub.close()


def open_application(
    hub: Hub,
    relation: RelationId,
    name: str,
    asked: dict[str, Any],
    first: dict[str, Any],
    clock: Callable[[], float | int] = time.monotonic,
) -> Relation:
    """Application ``name`` asking for ``relation``: when it asked goes into ``asked``, when
    its first sample came into ``first`` (read from ``clock``)."""
    asked[name] = clock()
    return Relation(
        hub.session,
        hub.keys,
        relation,
        application=name,
        callback=lambda _m: first.setdefault(name, clock()),
    )


def add_rooms(hub: Hub, trackers: int) -> Provider:
    """The static ``R -> T<k>`` of every tracker, from a provider of the bench's session."""
    edges = [EdgeAnnouncement("R", f"T{k}", "6D", static=True) for k in range(trackers)]
    room = Provider(hub.session, hub.keys, "room", edges)
    pose = (np.array([1.0, 0, 0, 0]), np.zeros(3), np.eye(6) * 1e-6)
    for name in room.edges:
        room.publish(name, ErrorPose(time.time_ns(), *pose))
    return room


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command")
    publisher = sub.add_parser("publish")
    for flag, kind in (("--rate", float), ("--providers", int), ("--edges", int), ("--port", int)):
        publisher.add_argument(flag, type=kind, required=True)
    publisher.add_argument("--domain", required=True)
    echoing = sub.add_parser("echo")
    probing = sub.add_parser("probe")
    echoing.add_argument("--bytes", type=int, required=True)
    probing.add_argument("--period", type=float, required=True)
    for command in (echoing, probing):
        command.add_argument("--port", type=int, required=True)
        command.add_argument("--domain", required=True)
    parser.add_argument("--part", choices=("cpu", "status", "both"), default="both")
    parser.add_argument("--rates", default="0,1,10,50", help="Hz; 0: announced, not publishing")
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument(
        "--compare",
        metavar="CHECKOUT",
        type=Path,
        help="also measure the agent of this checkout (run in its directory, by its .venv if it "
        "has one, else by this python)",
    )
    parser.add_argument("--applications", type=int, default=50)
    parser.add_argument("--every", type=float, default=2.0)
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    if args.command in ("publish", "echo", "probe"):
        return {"publish": publish, "echo": echo, "probe": probe}[args.command](args)
    result: dict[str, Any] = {"machine": f"{platform.machine()}, {os.cpu_count()} CPUs"}
    if args.part in ("cpu", "both"):
        rates = [float(r) for r in args.rates.split(",")]
        print("agent CPU, 20 providers x 10 edges:", flush=True)
        result["cpu"] = [cpu_part(None, rates, args.seconds, 20, 10)]
        if args.compare:
            result["cpu"].append(cpu_part(args.compare, rates, args.seconds, 20, 10))
    if args.part in ("status", "both"):
        print("agent status latency while applications are added:", flush=True)
        result["status"] = status_part(args.applications, args.every, 10, 10.0)
        s = result["status"]
        print(
            f"  status: median {1e3 * s['status_median_s']:.1f} ms, max "
            f"{1e3 * s['status_max_s']:.1f} ms over {s['status_answers']} answers "
            f"({s['status_unanswered']} unanswered); the echo process: median "
            f"{1e3 * s['echo_median_s']:.1f} ms, max {1e3 * s['echo_max_s']:.1f} ms; first "
            f"sample: median "
            f"{s['first_sample_median_s']:.2f} s, max {s['first_sample_max_s']:.2f} s"
        )
    args.output.parent.mkdir(parents=True, exist_ok=True)
    if args.output.exists():  # keep the other part's figures of an earlier run
        result = {**json.loads(args.output.read_text()), **result}
    args.output.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
