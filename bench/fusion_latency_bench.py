"""The demo's flow, live: latency and error of C->A fused asynchronously, fused synchronised
(the wait-for-all policy) and on the A.R.T. path alone, and the pose predicted for display.

Run: ``python -m bench.fusion_latency_bench [--phase-seconds S] [--cycles N] [--seed N]
[--parameters JSON] [--no-probes] [--output FILE]`` (defaults 15 s phases, one cycle, seed 7,
the template's fusion parameters; about two minutes, and 45 s more per further cycle). Prints a
table and writes ``--output``, by default ``bench/results/fusion_latency.json``. The processes
inherit ``ZENOH_CONFIG`` (``net.session``): ``ZENOH_CONFIG=bench/zenoh_options/<file> python -m
bench.fusion_latency_bench`` runs the flow with zenoh's options of that file.

The processes of ``ubitrack demo`` (agent, simulated database, HMD camera, A.R.T. tracker and
its DTrack adapter; the same flags, :mod:`ubitrack_agent.commands.demo`), with ``C -> HT``
served by the database from the scenario's truth (as ``bench.calibrated_tracking_bench``'s
*true* runs) so no calibration runs first, and this process as the application asking for
``C -> A``. Each phase starts once the host manager's warm pool is full
(``bench.steady_state``: the cold starts that refill it, after the flow took members, would
share the CPUs with the flow). Phases, in one run:

1. **asynchronous**: the flow of the paper's figure 6 with the fusion template's default
   policy (``asynchronous``: each estimate updates the filter and is published at once);
2. **synchronised**: the same running flow after a control command sets the fusion worker's
   ``policy`` to ``synchronised`` (estimates synchronised at each trigger and fused as
   simultaneous: the behaviour before);
3. **A.R.T. only**: the camera simulator stopped; the agent rewires ``C -> A`` to the A.R.T.
   path alone (no fusion hop);
4. **asynchronous again**: the camera back, fusion with the template's policy again (so the
   A.R.T.-only phase lies between two asynchronous ones: the load of this shared machine
   drifts between phases); with ``--cycles N``, phases 3 and 4 run N times in turn;
5. **camera only**: the A.R.T. tracker stopped; 2D-3D pose estimation alone, whose trigger no
   longer waits a frame for a hidden feature (``ubitrack_agent.services.triggers``).

In the fused phases the bench also times the fusion hop itself, paired per timestamp: the
arrival of the fusion's output minus the arrival of the estimate it came from at the
fusion's input, both seen by this process at the same moment; and the latency of the A.R.T.
path's estimates at the fusion's input: the output of the A.R.T. chain's last concatenation,
handed to the fusion in their container (``ubitrack_agent.services.local_wires``), read here as
zenoh carries it to this process. Each fused phase also reports the fusion
worker's counters over the phase (``fusion_counters``: what became of the samples it took).
The probes are themselves readers outside the container: its components then put those
values on zenoh too, which no reader of the demo makes them do (an encode and a put each, made
after the hand-over downstream has returned: ``ubitrack_agent.services.worker``,
``Worker._publish``); so an estimate handed to the fusion in the container reaches this process
after the fusion's output of it, and the fusion hop counts only the pairs whose input arrived first
(estimates that came to the fusion over zenoh). ``--no-probes`` leaves the probes out.

Per sample the application receives: latency (its arrival, ``time.time_ns()`` in the
subscriber's callback, minus its timestamp; one host, one clock), the error against the
scenario's truth at its timestamp, and the error against the truth at its arrival (what a
renderer drawing it at once shows). The first second of each phase (the rewiring) is left
out. Every 50 ms the application also asks for the pose 20 ms ahead of its clock
(``Relation.predict``) and compares it, and the latest sample it holds, with the truth at
that display time. The simulator's truth serves only to compute these errors.

The bench then compares each A.R.T.-only phase with the asynchronous phases just before and
after it: the fused C->A p50 minus the A.R.T.-only p50, each such gap and their median (the
issue's bound: at most 2 ms). On a shared machine whose load drifts, several cycles measure the
gap better than one: each pair of phases is a minute apart, not several.

Each phase also reports the CPU its processes used (``bench.cpu_use``, Linux), in percent of
one CPU, in all and by process: on a machine of few CPUs every path's latency depends on how
busy they are.
"""

from __future__ import annotations

import argparse
import json
import platform
import queue
import tempfile
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from bench.calibrated_tracking_bench import scenario_with_true_calibration
from bench.cpu_use import CpuUse, namer
from bench.steady_state import wait_for_warm_pool
from ubitrack_agent.commands.demo import Processes, dtrack_flags, simulator_arguments
from ubitrack_agent.core import decode, quaternions
from ubitrack_agent.core.errors import ExtrapolationError, NoDataError
from ubitrack_agent.io.application import Relation
from ubitrack_agent.net import config
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.session import open_session
from ubitrack_agent.net.transport import fetch_latest, put_command
from ubitrack_agent.sim_trackers.scenario import load_scenario

RESULTS = Path(__file__).parent / "results" / "fusion_latency.json"
SETTLE_S = 1.0
"""Seconds left out at the start of each phase (rewiring, filter start)."""
AHEAD_NS = 20_000_000
"""How far ahead of the clock the renderer-style question asks."""


def errors(sample: Any, world: Any, at_ns: int) -> tuple[float, float]:
    """Translation (mm) and rotation (degrees) error of ``sample`` against the truth at
    ``at_ns``."""
    q, t = world.pose("C", "A", at_ns)
    relative = quaternions.multiply(quaternions.conjugate(q), sample.rotation)
    return (
        float(np.linalg.norm(sample.translation - t)) * 1000,
        float(np.degrees(quaternions.angle(relative))),
    )


def demo_world(
    scratch: Path, seed: int, member: list[str], true_calibration: bool = True
) -> tuple[Any, dict[str, list[str]]]:
    """The demo's world: with ``true_calibration`` without a calibration to run, the figure-1
    scenario with ``C -> HT`` served true by the database (written into ``scratch``); else the
    demo's, ``C -> HT`` to be calibrated live into the store (``store``, a file in
    ``scratch``). The ``ubitrack`` arguments of its processes (``sim database``, ``sim camera``,
    ``sim art``, ``dtrack``, ``store``) on the network of the ``member`` flags, the
    simulators' noise drawn from ``seed``."""
    path = scenario_with_true_calibration(scratch) if true_calibration else None
    scenario = load_scenario(None if path is None else str(path))
    flag = [] if path is None else ["--scenario", str(path)]
    art_port = _free_port("udp")
    simulators = simulator_arguments(flag, art_port, seed)
    quiet = "--quiet"  # the benches print their own figures
    return scenario, {
        "sim database": ["sim", "database", quiet, *flag, *member],
        "sim camera": [*simulators["sim camera"], *member],
        "sim art": simulators["sim art"],
        "dtrack": ["dtrack", quiet, *dtrack_flags(scenario.art, art_port), *member],
        "store": ["store", quiet, str(scratch / "calibration.yaml"), *member],
    }


def own_network(args: argparse.Namespace, name: str) -> Any:
    """The hub's configuration from the command line's ``args``; without ``--listen``, a network
    of its own: a free loopback port and a domain named ``name`` and the port."""
    if not args.listen:
        port = _free_port("tcp")
        args.listen, args.domain = [f"tcp/127.0.0.1:{port}"], args.domain or f"{name}{port}"
    return config.from_arguments(args, role="hub")


def components(session: Any, keys: KeySpace) -> dict[str, Any]:
    replies = fetch_latest(session, keys.agent_status(), timeout=1.0)
    return json.loads(replies[0])["components"] if replies else {}


def wait_for_services(session: Any, keys: KeySpace, present: bool, timeout: float = 60) -> None:
    """Until every component is alive and fusion is (``present``) or is not among them."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        running = components(session, keys)
        services = {c["service"] for c in running.values()}
        alive = running and all(c["alive"] for c in running.values())
        if alive and ("fusion" in services) == present:
            return
        time.sleep(0.2)
    raise RuntimeError(f"the flow did not {'gain' if present else 'lose'} fusion in time")


def summarise(
    name: str, samples: list[tuple[int, Any]], world: Any, ahead: dict, art_times: set[int]
) -> dict:
    latencies = [(arrived - s.timestamp_ns) / 1e6 for arrived, s in samples]
    by_art = [
        lat for lat, (_, s) in zip(latencies, samples, strict=True) if s.timestamp_ns in art_times
    ]
    by_camera = [
        lat
        for lat, (_, s) in zip(latencies, samples, strict=True)
        if s.timestamp_ns not in art_times
    ]
    at_stamp = np.array([errors(s, world, s.timestamp_ns) for _, s in samples])
    at_arrival = np.array([errors(s, world, arrived) for arrived, s in samples])

    def rms(values: np.ndarray) -> float:
        return float(np.sqrt(np.mean(np.square(values))))

    return {
        "phase": name,
        "samples": len(samples),
        "latency_ms_p50": float(np.percentile(latencies, 50)),
        "latency_ms_p90": float(np.percentile(latencies, 90)),
        "art_stamped": len(by_art),
        "art_stamped_latency_ms_p50": float(np.median(by_art)) if by_art else None,
        "camera_stamped_latency_ms_p50": float(np.median(by_camera)) if by_camera else None,
        "error_mm_rms": rms(at_stamp[:, 0]),
        "error_deg_rms": rms(at_stamp[:, 1]),
        "error_at_arrival_mm_rms": rms(at_arrival[:, 0]),
        "predicted_20ms_mm_rms": rms(np.array(ahead["predicted"])) if ahead["predicted"] else None,
        "latest_at_display_mm_rms": rms(np.array(ahead["latest"])) if ahead["latest"] else None,
        "predictions": len(ahead["predicted"]),
        "prediction_errors": ahead["refused"],
    }


def fused_phase(
    session: Any,
    keys: KeySpace,
    measure: Callable[..., dict],
    parameters: dict[str, Any],
    art_times: set[int],
    probes: bool,
    name: str,
    policy: dict[str, Any],
) -> dict:
    """A phase of the fused flow with the fusion worker's ``parameters`` and ``policy`` set
    (a control command), also timing the fusion hop itself (with ``probes``): per timestamp,
    the arrival of the fusion's output minus the arrival of the estimate of that timestamp at
    its input (the two paired in the same moment, unlike two phases under a varying load)."""
    (fusion,) = [(i, c) for i, c in components(session, keys).items() if c["service"] == "fusion"]
    instance, spec = fusion
    if parameters or policy:
        command = {"parameters": {**parameters, **policy}}
        put_command(session, keys.control(instance), json.dumps(command))
    inputs: dict[int, int] = {}
    hops: list[float] = []
    art_inputs: list[float] = []

    def arrived_in(sample: Any) -> None:
        now = time.time_ns()
        stamp = decode(sample.payload.to_bytes()).timestamp_ns
        inputs.setdefault(stamp, now)
        if stamp in art_times:
            art_inputs.append((now - stamp) / 1e6)

    def arrived_out(sample: Any) -> None:
        now = time.time_ns()
        sent = inputs.get(decode(sample.payload.to_bytes()).timestamp_ns)
        if sent is not None:
            hops.append((now - sent) / 1e6)

    watches = []
    if probes:
        watches = [session.declare_subscriber(b["key"], arrived_in) for b in spec["inputs"]]
        watches.append(session.declare_subscriber(spec["outputs"]["fused"], arrived_out))
    before = worker_counters(session, keys, instance)
    try:
        result = measure(name)
    finally:
        for watch in watches:
            watch.undeclare()
    after = worker_counters(session, keys, instance)
    result["fusion_counters"] = {
        name: count - before.get(name, 0)
        for name, count in after.items()
        if isinstance(count, int) and count != before.get(name, 0)
    }
    result["art_at_fusion_ms_p50"] = float(np.median(art_inputs)) if art_inputs else None
    result["fusion_hop_ms_p50"] = float(np.median(hops)) if hops else None
    result["fusion_hop_ms_p90"] = float(np.percentile(hops, 90)) if hops else None
    print(json.dumps(result), flush=True)
    return result


def worker_counters(session: Any, keys: KeySpace, instance: str) -> dict[str, int]:
    """A worker's counters (``ubitrack_agent.services.worker.COUNTERS``), from its status."""
    replies = fetch_latest(session, keys.status(instance), timeout=1.0)
    return json.loads(replies[0])["counters"] if replies else {}


def process_names(session: Any, keys: KeySpace, children: Processes) -> Callable[[int], str]:
    """Names for the processes of the flow (``bench.cpu_use``): the children by role, the
    workers by service and instance (their status tells their pid)."""
    roles = {process.pid: role for role, process in children.running.items()}
    workers = {}
    for instance in components(session, keys):
        replies = fetch_latest(session, keys.status(instance), timeout=0.5)
        if replies:
            status = json.loads(replies[0])
            workers[status["pid"]] = f"{status['service']} {instance}"
    return namer(roles, workers)


def run_phase(
    seconds: float,
    relation: Relation,
    arrivals: queue.SimpleQueue,
    world: Any,
    art_times: set[int],
    names: Callable[[], Callable[[int], str]],
    name: str,
) -> dict:
    time.sleep(SETTLE_S)
    while not arrivals.empty():
        arrivals.get_nowait()
    cpu = CpuUse()
    cpu.start(time.monotonic())
    ahead: dict[str, Any] = {"predicted": [], "latest": [], "refused": 0}
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        display = time.time_ns() + AHEAD_NS
        latest = relation.latest()
        try:
            predicted = relation.predict(display)
        except (ExtrapolationError, NoDataError, TimeoutError):
            ahead["refused"] += 1
        else:
            ahead["predicted"].append(errors(predicted, world, display)[0])
            ahead["latest"].append(errors(latest, world, display)[0])
        time.sleep(0.05)
    used = cpu.stop(time.monotonic(), names())
    samples = []
    while not arrivals.empty():
        samples.append(arrivals.get_nowait())
    return summarise(name, samples, world, ahead, art_times) | {"cpu_percent": used}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--phase-seconds", type=float, default=15.0)
    parser.add_argument(
        "--cycles",
        type=int,
        default=1,
        help="how many times the A.R.T.-only and asynchronous phases run in turn (default 1)",
    )
    parser.add_argument("--seed", type=int, default=7, help="the simulators' noise seed")
    parser.add_argument(
        "--parameters",
        type=json.loads,
        default={},
        help="fusion parameters (JSON) set on the running worker for both fused phases, e.g. "
        "'{\"linear_noise\": 0.1}' (default: the template's)",
    )
    parser.add_argument(
        "--no-probes",
        action="store_true",
        help="do not time the fusion hop: no subscriber of this process on the fusion's inputs "
        "and output, which makes their producers put them on zenoh as well as hand them over in "
        "their container (an encode and a put each, after the hand-over)",
    )
    parser.add_argument(
        "--output", type=Path, default=RESULTS, help=f"results file (default {RESULTS})"
    )
    config.add_arguments(parser)
    args = parser.parse_args(argv)
    if args.cycles < 1:
        parser.error("--cycles must be at least 1")
    hub = own_network(args, "bench")
    member = config.member_flags(hub)
    keys = KeySpace(hub.key_prefix)
    children = Processes()
    phases = []
    with tempfile.TemporaryDirectory() as scratch:
        scenario, commands = demo_world(Path(scratch), args.seed, member)
        arrivals: queue.SimpleQueue = queue.SimpleQueue()
        try:
            children.start("agent", ["agent", "--quiet", *config.as_flags(hub)])
            with (
                open_session(config.member_of(hub)) as session,
                Relation(
                    session,
                    keys,
                    RelationId("C", "A", "6D"),
                    application="fusion-bench",
                    callback=lambda m: arrivals.put((time.time_ns(), m)),
                    keep_waiting=True,  # asked before the sensors start
                ) as relation,
            ):
                art_times: set[int] = set()  # the A.R.T. frames' timestamps
                watch = session.declare_subscriber(
                    keys.data(scenario.art.provider) + "/**",
                    lambda sample: art_times.add(decode(sample.payload.to_bytes()).timestamp_ns),
                )
                for name in ("sim database", "sim camera", "sim art", "dtrack"):
                    children.start(name, commands[name])
                relation.wait_for(timeout=90)
                wait_for_services(session, keys, present=True)
                wait_for_warm_pool(session, keys)  # measure the steady state
                world = scenario.world
                names = partial(process_names, session, keys, children)
                measure = partial(
                    run_phase, args.phase_seconds, relation, arrivals, world, art_times, names
                )
                fused = partial(
                    fused_phase,
                    session,
                    keys,
                    measure,
                    args.parameters,
                    art_times,
                    not args.no_probes,
                )
                phases.append(fused("asynchronous", {}))
                phases.append(fused("synchronised", {"policy": "synchronised"}))
                children.stop("sim camera")
                wait_for_services(session, keys, present=False)
                wait_for_warm_pool(session, keys)
                phases.append(measure("A.R.T. only"))
                print(json.dumps(phases[-1]), flush=True)
                for cycle in range(args.cycles):
                    if cycle:
                        children.stop("sim camera")
                        wait_for_services(session, keys, present=False)
                        wait_for_warm_pool(session, keys)
                        phases.append(measure("A.R.T. only"))
                        print(json.dumps(phases[-1]), flush=True)
                    children.start("sim camera", commands["sim camera"])
                    wait_for_services(session, keys, present=True)
                    wait_for_warm_pool(session, keys)  # its refill's imports load the CPUs
                    phases.append(fused("asynchronous again", {}))
                children.stop("sim art", "dtrack")
                wait_for_services(session, keys, present=False)
                wait_for_warm_pool(session, keys)
                phases.append(measure("camera only"))
                print(json.dumps(phases[-1]), flush=True)
                watch.undeclare()
        finally:
            children.stop_all()
    print_table(phases)
    print_cpu_table(phases)
    gaps = fusion_gaps(phases)
    print_gaps(gaps)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(
        json.dumps(
            {
                "command": f"python -m bench.fusion_latency_bench --phase-seconds "
                f"{args.phase_seconds:g} --cycles {args.cycles} --seed {args.seed}"
                + (f" --parameters '{json.dumps(args.parameters)}'" if args.parameters else ""),
                "date": time.strftime("%Y-%m-%d"),
                "machine": {"python": platform.python_version(), "cpus": _cpus()},
                "phases": phases,
                "fused_minus_art_only_ms": gaps,
            },
            indent=1,
        )
    )


def print_table(phases: list[dict]) -> None:
    print(
        "\n| phase | samples | latency p50 / p90 (ms) | p50 of A.R.T.- / camera-stamped | "
        "error at timestamp (mm / deg RMS) | error at arrival (mm RMS) | "
        "20 ms ahead: predicted / latest sample (mm RMS) | A.R.T. estimate at fusion p50; "
        "fusion hop p50 / p90 (ms) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for p in phases:
        ahead = (
            f"{p['predicted_20ms_mm_rms']:.2f} / {p['latest_at_display_mm_rms']:.2f} "
            f"({p['predictions']} answered, {p['prediction_errors']} refused)"
            if p["predicted_20ms_mm_rms"] is not None
            else f"refused ({p['prediction_errors']})"
        )
        hop = (
            f"{p['art_at_fusion_ms_p50']:.1f}; {p['fusion_hop_ms_p50']:.2f} / "
            f"{p['fusion_hop_ms_p90']:.2f}"
            if p.get("fusion_hop_ms_p50") is not None
            else "-"
        )
        split = " / ".join(
            "-" if p[k] is None else f"{p[k]:.1f}"
            for k in ("art_stamped_latency_ms_p50", "camera_stamped_latency_ms_p50")
        )
        print(
            f"| {p['phase']} | {p['samples']} | {p['latency_ms_p50']:.1f} / "
            f"{p['latency_ms_p90']:.1f} | {split} | "
            f"{p['error_mm_rms']:.2f} / {p['error_deg_rms']:.3f} | "
            f"{p['error_at_arrival_mm_rms']:.2f} | {ahead} | {hop} |"
        )


def fusion_gaps(phases: list[dict]) -> list[float]:
    """Fused C->A p50 minus A.R.T.-only p50, for each A.R.T.-only phase and each asynchronous
    phase just before or after it (ms)."""
    gaps = []
    for index, phase in enumerate(phases):
        if phase["phase"] != "A.R.T. only":
            continue
        for neighbour in (phases[index - 1], phases[index + 1]):
            if neighbour["phase"].startswith("asynchronous"):
                gaps.append(neighbour["latency_ms_p50"] - phase["latency_ms_p50"])
    return gaps


def print_gaps(gaps: list[float]) -> None:
    if not gaps:
        return
    within = sum(gap <= 2.0 for gap in gaps)
    print(
        f"\nfused C->A p50 minus A.R.T.-only p50 (ms): {', '.join(f'{g:.2f}' for g in gaps)}; "
        f"median {float(np.median(gaps)):.2f}; at most 2 ms: {within} of {len(gaps)}"
    )


def print_cpu_table(phases: list[dict]) -> None:
    """Each phase's CPU use (``bench.cpu_use``), in percent of one CPU: the total and the
    largest users."""
    print("\n| phase | CPU, % of one (all processes) | largest users (%) |")
    print("|---|---|---|")
    for p in phases:
        used = p["cpu_percent"]
        if isinstance(used, str):
            print(f"| {p['phase']} | {used} | - |")
            continue
        users = [(label, percent) for label, percent in used.items() if label != "total"]
        largest = ", ".join(f"{label} {percent:.0f}" for label, percent in users[:6])
        print(f"| {p['phase']} | {used['total']:.0f} | {largest} |")


def _cpus() -> int | None:
    import os

    return os.cpu_count()


def _free_port(kind: str) -> int:
    import socket

    with socket.socket(
        socket.AF_INET, {"udp": socket.SOCK_DGRAM, "tcp": socket.SOCK_STREAM}[kind]
    ) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


if __name__ == "__main__":
    main()
