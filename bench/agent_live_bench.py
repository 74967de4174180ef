"""The live agent on one host (issue [scale]): its CPU against the sensors' sample rate, and how
fast it answers its status while applications keep coming.

Everything on loopback with real zenoh and real processes. Two parts:

* ``cpu``: the agent alone (``ubitrack agent --no-host``, no query, so no worker), then with 20
  providers x 10 dynamic 6D edges (``io.provider.Provider``, all in one publishing process,
  ``python -m bench.agent_live_bench publish``) at 1, 10 and 50 Hz: the agent's CPU (its
  process's ``utime + stime`` from ``/proc``, ``bench.cpu_use``) over ``--seconds``, in percent
  of one core, beside the samples per second actually published. ``--compare CHECKOUT``
  measures the same with the agent of another checkout (run in its directory, so ``-m`` imports
  its code; by its ``.venv`` if it has one: e.g. ``git archive`` of the commit before the agent
  left the data path) in the same run, side by side.
* ``status``: the agent with its host manager (``--pool-size 2``) and 10 providers (each a
  tracker ``T<k>`` in room ``R`` seeing bodies ``H<k>_1``, ``H<k>_2`` at 10 Hz); applications
  (``io.application.Relation``) are added one every ``--every`` seconds, five relations per
  tracker (``H->T`` twice, ``R->H`` twice, ``H<k>_1->H<k>_2``), up to ``--applications`` (50)
  or until the machine has less than 3 GB of memory available. Throughout, the bench asks the
  agent's status every 50 ms (``<root>/agent/status``) and records each answer's latency;
  also each application's time to its first sample and the agent's plan times.

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
    settings = config.Settings(
        connect=(f"tcp/127.0.0.1:{args.port}",), listen=("tcp/127.0.0.1:0",), domain=args.domain
    )
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
            {"rate_hz": 0.0, "samples_per_s": 0.0, "agent_cpu_pct": agent_cpu(hub, seconds)}
        )
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
        print(f"  {name}: idle: agent {rows[0]['agent_cpu_pct']:5.2f} % of a core", flush=True)
    finally:
        hub.close()
    return {"agent": name, "rows": rows}


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
    """Asks the agent's status every ``period`` s on a thread; keeps (time, latency) pairs."""

    def __init__(self, hub: Hub, period: float = 0.05) -> None:
        self.samples: list[tuple[float, float]] = []
        self.unanswered = 0
        self._stop = threading.Event()
        self._hub, self._period = hub, period
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(self._period):
            started = time.monotonic()
            replies = fetch_latest(self._hub.session, self._hub.keys.agent_status(), timeout=5.0)
            if replies:
                self.samples.append((started, time.monotonic() - started))
            else:
                self.unanswered += 1

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10)


def status_part(applications: int, every: float, trackers: int, rate: float) -> dict:
    hub = Hub(None, "--pool-size", "2")
    publisher = room = None
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
            window_start = time.monotonic()
            time.sleep(every)
            latencies = [lat for t, lat in probe.samples if t >= window_start]
            status = hub.status() or {}
            rows.append(
                {
                    "applications": n,
                    "status_median_s": statistics.median(latencies) if latencies else None,
                    "status_max_s": max(latencies) if latencies else None,
                    "workers_alive": sum(c["alive"] for c in status.get("components", {}).values()),
                    "last_plan_s": status.get("planning", {}).get("last_plan_s"),
                }
            )
            r = rows[-1]
            print(
                f"  {n:3d} applications: status median {1e3 * (r['status_median_s'] or 0):6.1f} ms"
                f" max {1e3 * (r['status_max_s'] or 0):7.1f} ms; {r['workers_alive']} workers "
                f"alive; last plan {1e3 * (r['last_plan_s'] or 0):.1f} ms",
                flush=True,
            )
        time.sleep(5.0)
        probe.stop()
    finally:
        for relation in opened:
            relation.close()
        if room is not None:
            room.close()
        if publisher is not None:
            publisher.send_signal(signal.SIGTERM)
            publisher.wait(timeout=60)
        hub.close()
    latencies = [lat for _, lat in probe.samples]
    to_first = [first[name] - asked[name] for name in first]
    return {
        "trackers": trackers,
        "rate_hz": rate,
        "rows": rows,
        "status_median_s": statistics.median(latencies),
        "status_max_s": max(latencies),
        "status_answers": len(latencies),
        "status_unanswered": probe.unanswered,
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


def open_application(
    hub: Hub,
    relation: RelationId,
    name: str,
    asked: dict[str, float],
    first: dict[str, float],
) -> Relation:
    """Application ``name`` asking for ``relation``: when it asked goes into ``asked``, when
    its first sample came into ``first`` (``time.monotonic``)."""
    asked[name] = time.monotonic()
    return Relation(
        hub.session,
        hub.keys,
        relation,
        application=name,
        callback=lambda _m: first.setdefault(name, time.monotonic()),
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
    parser.add_argument("--part", choices=("cpu", "status", "both"), default="both")
    parser.add_argument("--rates", default="1,10,50")
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
    if args.command == "publish":
        return publish(args)
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
            f"({s['status_unanswered']} unanswered); first sample: median "
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
