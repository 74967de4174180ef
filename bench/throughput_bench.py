"""Data throughput of one host with containers (issue 28, "Done when": 20 providers into 20
concatenation chains on one 2-core host carry >= 20,000 samples/s with p99 <= 20 ms).

Run: ``python -m bench.throughput_bench [--rates 1000,2000,5000,10000,20000,40000]
[--seconds 5] [--chains 20] [--hops 2] [--cores 2] [--peers] [--across] [--zenoh-config FILE]
[--direct-callbacks] [--output FILE]``; prints the figures and writes them to ``--output``, by
default ``bench/results/throughput.json`` (the worker processes as zenoh clients of their host
manager, the default; ``throughput_peers.json`` with ``--peers``: as peers, ``ubitrack host
--workers-as-peers``). ``--zenoh-config`` names a zenoh configuration file every process of the
run starts from (``ZENOH_CONFIG``, ``net.session``): how zenoh's own options are compared
(``bench/zenoh_options/``); ``--direct-callbacks``: the application's subscribers called on
zenoh's receiving thread (:class:`DirectCallbacks`).

Everything is a real process on loopback with real zenoh (explicit endpoints, multicast off):

* this process is the hub (a peer listening on a free port, as the agent is) and the
  calibration database: it serves the static edges ``S<k>_<j>`` (a
  :class:`~ubitrack_agent.net.transport.LatestValuePublisher` each);
* a host manager (``python -m ubitrack_agent.services.host --cores N``) starts the components as the
agent
  would: the chains grouped by ``agent.placement.group_containers`` (one container per core,
  a chain's components together; with ``--across``, hop ``j`` of every chain in container ``j``,
  so samples cross between containers on the components' data keys) and sent in one
  ``start_group`` request per container;
* chain ``k`` reads provider ``k``'s dynamic ErrorPose and composes it in turn with ``--hops``
  static edges (one concatenation each, ``ubitrack_agent.services.components.basic``), the last one
  also published on the relation key of an application;
* one provider process (``bench.throughput_bench provide``) runs the ``--chains`` providers
  (:class:`~ubitrack_agent.io.provider.Provider`), each publishing ErrorPoses stamped with
  the time they are made, together at the total rate of each step;
* one application process (``bench.throughput_bench apply``) holds a
  :class:`~ubitrack_agent.io.application.Relation` per chain; a sample's latency is the time
  its callback runs minus the sample's timestamp (one clock: one host).

Per step of offered rate: samples offered and sent, delivered per second (samples of the
step's window that reached the application), the latency's median, 99th percentile and
largest, the CPU each process used (percent of one core; the host manager's children are
its containers and idle pool members), and where the samples went (``per_hop``: the provider's
puts, by hop the components' ``received``, ``missed`` and ``published`` counters over the step,
the samples the application took and counted ``missed``, and the samples lost between each
stage and the next; the application waits for the last samples until none came for 1 s, so a
late sample is not taken for a lost one). Before the first step, with everything started and no
sample flowing: each process's idle CPU and its sockets (``/proc/<pid>/fd``). The steps stop
after the first that breaks (fewer than 95 % delivered, or p99 above ``--break-ms``).

Growth: the bench's own work is O(samples) in the application process and
O(processes x steps) reads of ``/proc`` here.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.cpu_use import _TICKS_PER_S, descendants_cpu
from bench.report import run_header, write_results
from ubitrack_agent.net.session import CONFIG_VARIABLE

RESULTS = Path(__file__).with_name("results") / "throughput.json"
DEFAULT_RATES = "1000,2000,5000,10000,20000,40000"
SETTLE_S = 1.0
"""Quiet time between two steps (the last samples of a step drain)."""
MAX_SETTLE_S = 30.0
"""Longest wait for the last samples of a step (under overload they come seconds late)."""
COUNTED = ("received", "missed", "published")
"""The components' counters read per hop (``services.worker.COUNTERS``)."""
HOST = "tp"
"""The host manager's name."""


def _relation(chain: int) -> Any:
    from ubitrack_agent.net.keys import RelationId

    return RelationId(f"W{chain}", f"H{chain}", "6D")


def _pose(t_ns: int, seed: int) -> Any:
    from ubitrack_agent.core import ErrorPose

    rng = np.random.default_rng(seed)
    a = rng.normal(size=(6, 6)) * 1e-3
    q = rng.normal(size=4)
    return ErrorPose(t_ns, q / np.linalg.norm(q), rng.normal(size=3), a @ a.T + np.eye(6) * 1e-6)


def specs(keys: Any, chains: int, hops: int) -> dict[str, Any]:
    """The components of the chains, by instance: chain ``k``'s hop ``j`` composes static edge
    ``S<k>_<j>`` with the previous hop's output (the provider's edge for the first); the last
    hop also serves the application's relation key."""
    from ubitrack_agent.net.spec import ComponentSpec, InputBinding

    found = {}
    for k in range(chains):
        source, from_worker = keys.data(f"p{k}/T_H"), False
        for j in range(hops):
            instance = f"c{k}-{j}"
            inputs = (
                InputBinding("AB", keys.data(f"db/S{k}_{j}"), static=True),
                InputBinding("BC", source, trigger=True, from_worker=from_worker),
            )
            last = j == hops - 1
            relations = {"AC": (keys.relation(_relation(k)),)} if last else {}
            outputs = {"AC": keys.data(f"{instance}/out")}
            found[instance] = ComponentSpec(
                instance, "concatenation", inputs, outputs, relations=relations
            )
            source, from_worker = outputs["AC"], True
    return found


# -- the provider and application processes -------------------------------------------------


def provide(args: argparse.Namespace) -> int:
    """``--chains`` providers publishing together at each rate of ``--rates`` for
    ``--seconds``; one JSON line per step on standard output (its window and what was sent)."""
    from ubitrack_agent.io.provider import EdgeAnnouncement, Provider
    from ubitrack_agent.net import config
    from ubitrack_agent.net.keys import KeySpace
    from ubitrack_agent.net.session import open_session

    settings = config.from_arguments(args, role="member")
    keys = KeySpace(settings.key_prefix)
    rates = [float(r) for r in args.rates.split(",")]
    with open_session(settings) as session:
        providers = [
            Provider(session, keys, f"p{k}", [EdgeAnnouncement("T", "H", "6D", rate=1000.0)])
            for k in range(args.chains)
        ]
        templates = [_pose(1, k) for k in range(args.chains)]
        print(json.dumps({"ready": True}), flush=True)
        for rate in rates:
            if sys.stdin.readline().strip() != "go":
                break
            sent, start = _publish_step(providers, templates, rate, args.seconds)
            end = time.time_ns()
            print(json.dumps({"rate": rate, "sent": sent, "start": start, "end": end}), flush=True)
        for provider in providers:
            provider.close()
    return 0


def _publish_step(providers: list, templates: list, rate: float, seconds: float) -> tuple:
    """One sample of every provider per tick, ``rate / providers`` ticks a second (a tick
    that is due late is published at once, stamped when made); the samples sent and the
    window's start (ns)."""
    ticks_per_s = rate / len(providers)
    total = int(seconds * ticks_per_s)
    start_ns, start = time.time_ns(), time.perf_counter()
    sent = tick = 0
    while tick < total:
        due = min(total, int((time.perf_counter() - start) * ticks_per_s) + 1)
        if tick >= due:
            time.sleep(max(0.0, (tick / ticks_per_s) - (time.perf_counter() - start)))
            continue
        for _ in range(due - tick):
            now = time.time_ns()
            for provider, template in zip(providers, templates, strict=True):
                provider.publish("T_H", template.restamped(now))
                sent += 1
        tick = due
    return sent, start_ns


def apply(args: argparse.Namespace) -> int:
    """An application holding one relation per chain; for each step window (a JSON line on
    standard input) it waits for the last samples, then prints the window's arrivals and
    latencies (a JSON line); ends on any other line."""
    from ubitrack_agent.io.application import Relation
    from ubitrack_agent.net import config
    from ubitrack_agent.net.keys import KeySpace
    from ubitrack_agent.net.session import open_session

    settings = config.from_arguments(args, role="member")
    keys = KeySpace(settings.key_prefix)
    stamps: list[int] = []
    arrivals: list[int] = []

    def take(sample: Any) -> None:
        arrivals.append(time.time_ns())
        stamps.append(sample.timestamp_ns)

    with open_session(settings) as opened:
        session = DirectCallbacks(opened) if args.direct_callbacks else opened
        relations = [
            Relation(session, keys, _relation(k), application=f"a{k}", callback=take)
            for k in range(args.chains)
        ]
        print(json.dumps({"ready": True}), flush=True)
        while (line := sys.stdin.readline()).startswith("{"):
            window = json.loads(line)
            count = settled(stamps)
            figures = window_figures(stamps[:count], arrivals[:count], window)
            figures["missed"] = sum(relation.counters["missed"] for relation in relations)
            print(json.dumps(figures), flush=True)
        for relation in relations:
            relation.close()
    return 0


def settled(stamps: list[int]) -> int:
    """The samples taken once none came for :data:`SETTLE_S` (at most :data:`MAX_SETTLE_S`):
    a late sample is counted as delivered, not lost."""
    deadline = time.monotonic() + MAX_SETTLE_S
    count = -1
    while count != len(stamps) and time.monotonic() < deadline:
        count = len(stamps)
        time.sleep(SETTLE_S)
    return len(stamps)


class DirectCallbacks:
    """A session whose subscribers' plain callables run on zenoh's receiving thread
    (``zenoh.handlers.Callback(..., indirect=False)``) instead of on a thread zenoh-python
    starts per subscriber and wakes per sample (its default): what the application's side
    would save without that hand-off (``--direct-callbacks``; the library does not do it:
    ``net.transport.on_zenoh_thread``)."""

    def __init__(self, session: Any) -> None:
        self._session = session

    def __getattr__(self, name: str) -> Any:
        return getattr(self._session, name)

    def declare_subscriber(self, key: str, handler: Any, **options: Any) -> Any:
        import zenoh

        if callable(handler) and not isinstance(handler, zenoh.handlers.Callback):
            handler = zenoh.handlers.Callback(handler, indirect=False)
        return self._session.declare_subscriber(key, handler, **options)


def window_figures(stamps: list[int], arrivals: list[int], window: dict) -> dict[str, Any]:
    """The samples stamped in ``window`` that arrived, and their latency (ms)."""
    t = np.array(stamps, dtype=np.int64)
    inside = (t >= window["start"]) & (t <= window["end"])
    values = (np.array(arrivals, dtype=np.int64)[inside] - t[inside]) / 1e6
    if not values.size:
        return {"delivered": 0, "latency_ms": None}
    return {
        "delivered": int(values.size),
        "latency_ms": {
            "p50": round(float(np.percentile(values, 50)), 2),
            "p99": round(float(np.percentile(values, 99)), 2),
            "max": round(float(values.max()), 2),
        },
    }


# -- the bench ------------------------------------------------------------------------------


def _read_json(process: subprocess.Popen) -> Any:
    line = process.stdout.readline()
    if not line:
        raise RuntimeError(f"process {process.pid} ended (exit {process.wait()})")
    return json.loads(line)


def sockets(pid: int) -> int:
    """Open sockets of process ``pid`` (``/proc/<pid>/fd`` links to ``socket:``)."""
    count = 0
    try:
        for fd in os.listdir(f"/proc/{pid}/fd"):
            try:
                count += os.readlink(f"/proc/{pid}/fd/{fd}").startswith("socket:")
            except OSError:
                continue
    except OSError:
        return 0
    return count


def cpu_percent(before: dict[int, int], after: dict[int, int], seconds: float, roles) -> dict:
    """Percent of one core per role (processes of one role added up)."""
    used: dict[str, float] = {}
    for pid, ticks in after.items():
        role = roles(pid)
        share = (ticks - before.get(pid, ticks)) / _TICKS_PER_S / seconds * 100
        used[role] = round(used.get(role, 0.0) + share, 1)
    return dict(sorted(used.items()))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.throughput_bench")
    parser.add_argument("--rates", default=DEFAULT_RATES, help=f"(default {DEFAULT_RATES})")
    parser.add_argument("--seconds", type=float, default=5.0, help="per step (default 5)")
    parser.add_argument("--chains", type=int, default=20, help="providers and chains (20)")
    parser.add_argument("--hops", type=int, default=2, help="concatenations per chain (2)")
    parser.add_argument("--cores", type=int, default=2, help="containers (host --cores, 2)")
    parser.add_argument("--break-ms", type=float, default=200.0, help="p99 that breaks (200)")
    parser.add_argument(
        "--peers",
        action="store_true",
        help="the host manager's worker processes as zenoh peers (host --workers-as-peers)",
    )
    parser.add_argument("--idle-s", type=float, default=5.0, help="idle window (default 5)")
    parser.add_argument(
        "--across",
        action="store_true",
        help="hop j of every chain in container j (one per hop), so each sample crosses from "
        "container to container over zenoh on the components' data keys, instead of the "
        "agent's grouping (a chain's components together)",
    )
    parser.add_argument(
        "--zenoh-config",
        type=Path,
        default=None,
        help="zenoh configuration file every process starts from (ZENOH_CONFIG; e.g. one of "
        "bench/zenoh_options/; default: none, or ZENOH_CONFIG as set)",
    )
    parser.add_argument(
        "--output",
        type=Path,
        default=None,
        help=f"results file (default {RESULTS}, throughput_peers.json with --peers)",
    )
    parser.add_argument(
        "--direct-callbacks",
        action="store_true",
        help="the application's subscribers call back on zenoh's receiving thread "
        "(no thread hand-off per sample; an experiment, not what the library does)",
    )
    sub = parser.add_subparsers(dest="part")
    for name in ("provide", "apply"):
        part = sub.add_parser(name)
        part.add_argument("--direct-callbacks", action="store_true")
        part.add_argument("--rates", default=DEFAULT_RATES)
        part.add_argument("--seconds", type=float, default=5.0)
        part.add_argument("--chains", type=int, default=20)
        from ubitrack_agent.net import config, logs

        logs.add_log_level_argument(part)
        config.add_arguments(part)
    args = parser.parse_args(argv)
    if args.part is not None:
        from ubitrack_agent.net import logs

        logs.configure(args.log_level)
    if args.part == "provide":
        return provide(args)
    if args.part == "apply":
        return apply(args)
    if args.zenoh_config is not None:  # inherited by every process of the run
        os.environ[CONFIG_VARIABLE] = str(args.zenoh_config.resolve())
    default = RESULTS.with_name("throughput_peers.json") if args.peers else RESULTS
    write_results(args.output or default, bench(args))
    return 0


def across(components: dict[str, Any], hops: int) -> dict[str, Any]:
    """``--across``: container ``<host>-<j>`` holds hop ``j`` of every chain."""
    from ubitrack_agent.net.spec import GroupSpec

    return {
        f"{HOST}-{j}": GroupSpec(
            f"{HOST}-{j}",
            tuple(spec for name, spec in components.items() if name.endswith(f"-{j}")),
        )
        for j in range(hops)
    }


def start_groups(session: Any, keys: Any, host: str, groups: dict[str, Any]) -> None:
    """Send each group to the host manager in one ``start_group`` request (as the agent's
    ``agent.hosts`` does); RuntimeError if one is refused."""
    from ubitrack_agent.net.host_protocol import StartGroup, encode_request

    for group in groups.values():
        replies = list(
            session.get(
                keys.host_request(host), payload=encode_request(StartGroup(group)), timeout=10
            )
        )
        if not replies or replies[0].ok is None:
            raise RuntimeError(f"start_group {group.container}: refused or no answer")


def bench(args: argparse.Namespace) -> dict[str, Any]:
    """Start the host manager, its containers, the provider and the application; measure idle,
    then each step of ``--rates``."""
    from bench.dataflow_bench import Network
    from ubitrack_agent.agent.placement import group_containers
    from ubitrack_agent.core import encode
    from ubitrack_agent.net.transport import LatestValuePublisher

    net = Network()
    components = specs(net.keys, args.chains, args.hops)
    groups = (
        across(components, args.hops)
        if args.across
        else group_containers(components, dict.fromkeys(components, HOST), {HOST: args.cores})
    )
    results: dict[str, Any] = {
        **run_header(),
        "chains": args.chains,
        "hops": args.hops,
        "containers": {name: len(group.components) for name, group in groups.items()},
        "seconds_per_step": args.seconds,
        "workers_as_peers": args.peers,
        "across": args.across,
        "zenoh_config": os.environ.get(CONFIG_VARIABLE),
        "application_direct_callbacks": args.direct_callbacks,
    }
    statics = []
    try:
        for k in range(args.chains):
            for j in range(args.hops):
                publisher = LatestValuePublisher(net.session, net.keys.data(f"db/S{k}_{j}"))
                publisher.put(encode(_pose(1, 1000 * k + j)))
                statics.append(publisher)
        manager, application, provider = start(net, args, groups, set(components))
        roles = _roles(net, groups, manager.pid, provider.pid, application.pid)
        results["idle"] = idle(args.idle_s, roles)
        results["steps"] = steps(net, args, provider, application, roles)
    finally:
        for publisher in statics:
            publisher.undeclare()
        net.close()
    results["targets"] = {"delivered_per_s": 20000, "p99_ms": 20}
    return results


def start(net: Any, args: argparse.Namespace, groups: dict[str, Any], components: set[str]):
    """The host manager and its containers (every component's token up), the application
    and the provider, ready."""
    from tests.integration.zenoh_helpers import wait_until

    quiet = ("--log-level", "WARNING")
    peers = ("--workers-as-peers",) if args.peers else ()
    manager = net.spawn(
        "-m",
        "ubitrack_agent.services.host",
        "--name",
        HOST,
        "--cores",
        str(args.cores),
        "--quiet",
        *peers,
        *quiet,
    )
    watch = net.session.liveliness().declare_subscriber(net.keys.all_workers(), history=True)
    wait_until(lambda: _host_up(net, HOST), timeout=60, interval=0.2)
    start_groups(net.session, net.keys, HOST, groups)
    alive: set[str] = set()

    def all_alive() -> bool:
        while (sample := watch.try_recv()) is not None:
            alive.add(str(sample.key_expr).split("/")[-2])
        return alive >= components

    wait_until(all_alive, timeout=120, interval=0.2)
    watch.undeclare()
    chains = ("--chains", str(args.chains))
    direct = ("--direct-callbacks",) if args.direct_callbacks else ()
    application = net.spawn(
        "-m", "bench.throughput_bench", "apply", *chains, *direct, *quiet, pipes=True
    )
    provider = net.spawn(
        "-m",
        "bench.throughput_bench",
        "provide",
        *chains,
        "--rates",
        args.rates,
        "--seconds",
        str(args.seconds),
        *quiet,
        pipes=True,
    )
    _read_json(application), _read_json(provider)
    time.sleep(2.0)  # links up, static edges fetched
    return manager, application, provider


def steps(
    net: Any, args: argparse.Namespace, provider: Any, application: Any, roles: Any
) -> list[dict[str, Any]]:
    """Each rate of ``--rates`` in turn until one breaks (:func:`broken`)."""
    found = []
    counted = hop_counts(net, args.chains, args.hops)
    for rate in [float(r) for r in args.rates.split(",")]:
        before, at = descendants_cpu(os.getpid()), time.monotonic()
        provider.stdin.write("go\n")
        provider.stdin.flush()
        window = _read_json(provider)
        inputs = input_latencies(net, args.chains, args.hops)
        after, seconds = descendants_cpu(os.getpid()), time.monotonic() - at
        application.stdin.write(json.dumps(window) + "\n")
        application.stdin.flush()
        got = _read_json(application)
        counted, previous = hop_counts(net, args.chains, args.hops), counted
        counted |= {"application_received": got["delivered"], "application_missed": got["missed"]}
        previous["application_received"] = 0  # counted per window, not since the start
        span = (window["end"] - window["start"]) / 1e9
        cpu = cpu_percent(before, after, seconds, roles)
        delivered = got["delivered"] / span
        step = {
            "offered_per_s": rate,
            "sent_per_s": round(window["sent"] / span),
            "delivered_per_s": round(delivered),
            "delivered_fraction": round(got["delivered"] / max(1, window["sent"]), 3),
            "latency_ms": got["latency_ms"],
            "hop_input_latency_ms": inputs,
            "per_hop": per_hop(window["sent"], previous, counted, args.hops),
            "cpu_percent": cpu,
            "cpu_us_per_sample": {
                role: round(share / 100 / max(delivered, 1) * 1e6, 1) for role, share in cpu.items()
            },
            "load_average": round(os.getloadavg()[0], 2),
        }
        found.append(step)
        print(json.dumps(step), flush=True)
        if broken(step, args.break_ms):
            break
    return found


def input_latencies(net: Any, chains: int, hops: int) -> dict[str, Any]:
    """By hop, the median over the chains of each component's own median latency of its
    dynamic input at the step's end (``latency_ms`` in its status: its clock when it took a
    sample minus the sample's timestamp): where along the chain the delay builds up."""
    from ubitrack_agent.net.transport import fetch_latest

    found: dict[str, Any] = {}
    for j in range(hops):
        medians = []
        for k in range(chains):
            for payload in fetch_latest(net.session, net.keys.status(f"c{k}-{j}"), timeout=1.0):
                medians += [
                    v for key, v in json.loads(payload)["latency_ms"].items() if "db/" not in key
                ]
        found[f"hop{j}"] = round(float(np.median(medians)), 2) if medians else None
    return found


def hop_counts(net: Any, chains: int, hops: int) -> dict[str, int]:
    """By hop, the components' ``received``, ``missed`` and ``published`` counters (their
    status) added up over the chains, and ``missing``: components that did not answer."""
    from ubitrack_agent.net.transport import fetch_latest

    found = {"missing": 0}
    for j in range(hops):
        for name in COUNTED:
            found[f"hop{j}_{name}"] = 0
        for k in range(chains):
            payloads = fetch_latest(net.session, net.keys.status(f"c{k}-{j}"), timeout=1.0)
            if not payloads:
                found["missing"] += 1
                continue
            counters = json.loads(payloads[0])["counters"]
            for name in COUNTED:
                found[f"hop{j}_{name}"] += counters.get(name, 0)
    return found


def per_hop(sent: int, before: dict[str, int], after: dict[str, int], hops: int) -> dict:
    """Where the samples of a step went (the change of the counters over the step, taken after
    the application's wait for the last samples): the provider's puts; by hop, the samples its
    components received, counted missed (numbers never seen: ``net.sequence``) and published;
    the samples the application took and counted missed; and ``lost`` between each stage and
    the next (what one sent minus what the next received)."""
    stages = {"provider_sent": sent}
    for name in after:
        if name.startswith(("hop", "application")):
            stages[name] = after[name] - before.get(name, 0)
    chain = ["provider_sent"]
    for j in range(hops):
        chain += [f"hop{j}_received", f"hop{j}_published"]
    chain.append("application_received")
    stages["lost"] = {
        f"{a}->{b}": stages[a] - stages[b] for a, b in zip(chain[::2], chain[1::2], strict=True)
    }
    stages["missing_status"] = after["missing"]
    return stages


def _host_up(net: Any, host: str) -> bool:
    from ubitrack_agent.net.host_protocol import Status, encode_request

    replies = list(
        net.session.get(net.keys.host_request(host), payload=encode_request(Status()), timeout=1)
    )
    return any(reply.ok is not None for reply in replies)


def _roles(net: Any, groups: dict, manager: int, provider: int, app: int):
    """A function naming each process of the run by its role (containers by name, from their
    status)."""
    from ubitrack_agent.net.transport import fetch_latest

    named = {
        os.getpid(): "hub (bench)",
        manager: "host manager",
        provider: "provider",
        app: "application",
    }
    for name in groups:
        for payload in fetch_latest(net.session, net.keys.status(name), timeout=2.0):
            named[json.loads(payload)["pid"]] = f"container {name}"
    return lambda pid: named.get(pid, "pool member")


def idle(seconds: float, roles) -> dict[str, Any]:
    """CPU and sockets of every process with no sample flowing."""
    before, at = descendants_cpu(os.getpid()), time.monotonic()
    time.sleep(seconds)
    after = descendants_cpu(os.getpid())
    counted: dict[str, int] = {}
    for pid in after:
        counted[roles(pid)] = counted.get(roles(pid), 0) + sockets(pid)
    return {
        "cpu_percent": cpu_percent(before, after, time.monotonic() - at, roles),
        "sockets": dict(sorted(counted.items())),
    }


def broken(step: dict[str, Any], break_ms: float) -> bool:
    """Whether a step broke: fewer than 95 % of the samples sent delivered, or a p99 above
    ``break_ms``."""
    latency = step["latency_ms"]
    return step["delivered_fraction"] < 0.95 or latency is None or latency["p99"] > break_ms


if __name__ == "__main__":
    raise SystemExit(main())
