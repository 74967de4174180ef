"""Switches of the data flow as the application sees them (issue 29): every sample of ``C -> A``
the application receives in the second after each change, against the simulator's truth.

Run: ``python -m bench.switch_bench [--events N] [--seed S] [--dwell LO,HI] [--kinds K;K]
[--calibration live|true] [--trace] [--output FILE]`` (defaults: 20 events of each kind, seed
7, 2-4 s between events; about 10 minutes and the calibration's; ``--events 2`` for a smoke
run of a minute; ``--kinds`` only those kinds, with the ways back they need; ``--trace`` also
records, from each event to the next, the liveliness tokens of workers, containers,
providers and measured edges, control commands, the hand-over's messages, each input's first
and last sample and the relation's gaps: where a gap's time goes). Prints tables, and how
often each measured edge's token left (``io.flowing``: its sensor stopped, or a false alarm;
every run), and writes ``bench/results/switch.json`` (or ``FILE``).

The world is the demo's: the paper's figure-1 scenario
(``sim_trackers/scenarios/paper_figure1.yaml``), the agent with its host manager, the
calibration database and store, the simulated HMD camera and A.R.T. tracker with its DTrack
adapter, and this process as the application asking for ``C -> A``. ``C -> HT`` is calibrated
live first, as the demo does it (``--calibration live``, the default: saved in the store, which
serves it from then on, its error shared by every sample of the run as in a real room), or
served by the database from the scenario's truth (``--calibration true``: the idealised world
of the runs before session 23, as :mod:`bench.fusion_latency_bench`'s).

Events, each kind ``--events`` times, in an order drawn from ``--seed``
among those the state allows:

* **A.R.T. off** / **A.R.T. back**: the tracker's simulator and its DTrack adapter stopped
  (SIGTERM; the provider leaves) / started again; the flow goes from fused to camera only and
  back. The simulator first, the adapter once it has ended (the tracker silent, then its
  provider gone 0.1-0.3 s later), or with ``--sensor-stop together`` both at once (a tracking
  PC shut down: the provider gone as the data stops), as for the better tracker below;
* **camera off** / **camera back**: the camera's simulator stopped / started; fused to A.R.T.
  only and back;
* **worker killed**: the process running the component that puts on the relation key (its
  container, with the rest of the derivation) SIGKILLed while both sensors run; its host
  manager restores it (with ``--replicas``, a copy in another container serves meanwhile);
* **agent killed** / **agent stopped**: the agent SIGKILLed / stopped cleanly (SIGTERM) while
  both sensors run, and started again at once; the new agent adopts the running flow;
* **better tracker joins** / **leaves**: a second A.R.T.-like tracker, placed elsewhere in the
  room and with a third of the position noise (:func:`better_tracker`), started while both
  sensors run and stopped before anything else happens: fused from two estimates to three and
  back.

An event that starts a sensor happens at the sensor's first measurement after its processes
were launched (its first sample on any of its data keys, as this process receives it): its
processes take 1-3 s to start, during which the old flow goes on, which is no switch (the demo
times its phases the same way). The others happen when the bench acts. After each event the
bench waits until the flow has a fusion component or not, as the new state wants, then for a
time drawn from ``--dwell``. The simulator's truth is used only to
print errors (the system gets nothing from it).

What is recorded: every sample on the relation's key as a plain zenoh subscriber sees it (the
wire), its arrival time, and whether :class:`~ubitrack_agent.io.application.Relation` passes it
on (a sample stamped no later than one passed on is kept for lookups but not passed on, and
counted ``out_of_order``: ``docs/protocol.md``). Per event, over the samples stamped in the
second after it: the largest translation and rotation error, the p99, how many lie beyond "3
sigma" of their own covariance (NEES above the chi-square quantile of 99.73 % for 6 degrees of
freedom, 20.06), the mean NEES against its 95 % interval over the kind's events (each event's
mean NEES one batch: :func:`bench.synthetic.nees_over_batches`; the samples of one second are
correlated, so the chi-square(6 n) / n interval of ``n`` independent samples, printed beside
it, is too narrow),
the largest gap between arrivals of samples passed on, from 0.5 s before to 1 s after the event
(ms and frames of the faster sensor; a silence that outlasts that window is not in it, and an
event with no sample in the second after is left out of its kind's figures but counted), the
same up to the next event, over every event (the old flow is retired, and relation routes move,
``HAND_OVER_HOLD_S`` after the new one is alive: after that second; a silence ends before the
next event, which waits for the flow), and duplicates (a timestamp seen before) and
out-of-order samples on the wire.
How many of those samples lie beyond the larger of the two flows' steady p99 error, beside
the range (95 %) a steady flow would have there (its 1 % tail, binomial): "no sample over the
p99" cannot hold even without a switch, a tail no heavier than the steady state's can.
The steady state of each flow (fused, camera only, A.R.T. only, fused with the better tracker)
is every sample stamped from
1.5 s after an event to the next event: its p99 errors are the issue's bound for a switch
between two flows (the larger of the two), its gaps between arrivals (p99, largest) the
flow's own, to compare a switch's gap with, and its mean NEES with the 95 % interval over its
stretches (each from one event to the next a batch).
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import os
import platform
import random
import signal
import tempfile
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import yaml
from scipy.stats import binom, chi2

from bench.calibrated_tracking_bench import scenario_with_true_calibration
from bench.fusion_latency_bench import (
    _free_port,
    demo_world,
    errors,
    own_network,
    wait_for_services,
)
from bench.steady_state import wait_for_warm_pool
from bench.synthetic import THREE_SIGMA_NEES, nees, nees_over_batches
from ubitrack_agent.commands.demo import (
    Processes,
    calibrate_live,
    dtrack_flags,
    simulator_arguments,
)
from ubitrack_agent.core import decode
from ubitrack_agent.core.errors import MeasurementError
from ubitrack_agent.io.application import Relation
from ubitrack_agent.net import config
from ubitrack_agent.net.host_protocol import Status, encode_request
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.session import open_session
from ubitrack_agent.net.transport import fetch_latest
from ubitrack_agent.services.handover import PUT, hand_over_key
from ubitrack_agent.sim_trackers.scenario import load_scenario

RESULTS = Path(__file__).parent / "results" / "switch.json"
C_A = RelationId("C", "A", "6D")
WINDOW_S = 1.0
"""The second after an event whose samples are judged."""
BEFORE_S = 0.5
"""How long before an event the gap is looked for (the old flow's last samples)."""
STEADY_AFTER_S = 1.5
"""Samples stamped this long after an event and before the next count as the steady state."""
TRACED_GAP_MS = 25
"""Gaps between samples on the relation's key that ``--trace`` shows."""
STEADY_TAIL = 0.01
"""The share of a steady state's samples beyond its p99: what the second after a switch holds
beyond it too if the switch adds no error (the issue's bound, the larger p99 of the two flows,
taken as a tail share: 1 % of any flow's own samples lie beyond its p99)."""
KINDS = (
    "A.R.T. off",
    "A.R.T. back",
    "camera off",
    "camera back",
    "worker killed",
    "agent killed",
    "agent stopped",
    "better tracker joins",
    "better tracker leaves",
)
SENSORS = {"A.R.T.": "art", "camera": "camera", "better tracker": "better"}
"""The sensor each kind of event stops or starts, by the kind's first words."""
PROCESSES = {
    "art": ("sim art", "dtrack"),
    "camera": ("sim camera",),
    "better": ("sim better", "dtrack better"),
}
"""The processes of each sensor: a tracker's simulator and its DTrack adapter."""
FLOWS = {  # sensors running -> the flow serving C->A
    frozenset({"art", "camera"}): "fused",
    frozenset({"camera"}): "camera only",
    frozenset({"art"}): "A.R.T. only",
    frozenset({"art", "camera", "better"}): "fused with the better tracker",
}
ALLOWED = {
    frozenset({"art", "camera"}): (
        "A.R.T. off",
        "camera off",
        "worker killed",
        "agent killed",
        "agent stopped",
        "better tracker joins",
    ),
    frozenset({"camera"}): ("A.R.T. back",),
    frozenset({"art"}): ("camera back",),
    frozenset({"art", "camera", "better"}): ("better tracker leaves",),
}
"""The events each state allows: from two sensors one leaves, the fusion's container is
killed, the agent is killed or stopped and started again, or the better tracker joins; from
one, the other comes back; the better tracker leaves before anything else happens."""
BETTER = {"frame": "ART2", "translation": [0.4, -1.8, 2.2], "euler_deg": [0, 0, 35]}
"""Where the better tracker hangs in the room (child of ART)."""
PROVIDERS = {"art": "ART", "camera": "camera", "better": BETTER["frame"]}
"""The provider of each sensor, whose data keys tell its first measurement."""
SENSOR_START_S = 60.0
"""The longest wait for a started sensor's first measurement (its processes' imports)."""
BETTER_NOISE = {"position_mm": 0.1, "rotation_deg": 0.02}
"""Its noise: a third of the A.R.T. tracker's position noise, under half its rotation noise."""


@dataclass
class Wire:
    """Every sample on the relation's key: (arrival ns, timestamp ns, sample, passed on)."""

    samples: list[tuple[int, int, Any, bool]] = field(default_factory=list)
    newest: int = -1
    rejected: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)

    def take(self, zenoh_sample: Any) -> None:
        arrived = time.time_ns()
        try:
            sample = decode(zenoh_sample.payload.to_bytes())
        except MeasurementError:
            self.rejected += 1
            return
        with self.lock:
            passed = sample.timestamp_ns > self.newest
            self.newest = max(self.newest, sample.timestamp_ns)
            self.samples.append((arrived, sample.timestamp_ns, sample, passed))


@dataclass
class Trace:
    """With ``--trace``: what else happens on the network, to find where a gap's time goes
    (arrival ns, what, key): samples on the relation's key either side of a gap longer than
    :data:`TRACED_GAP_MS`, liveliness tokens of workers, containers, providers and measured
    edges coming and going, the agent's and host managers' control commands, the hand-over's
    claims and answers, and the latest sample on each data key (the inputs of the flows)."""

    items: list[tuple[int, str, str]] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def note(self, what: str, zenoh_sample: Any) -> None:
        with self.lock:
            self.items.append((time.time_ns(), what, str(zenoh_sample.key_expr)))

    def declare(self, session: Any, keys: KeySpace) -> list[Any]:
        """Its subscribers (undeclared by the caller)."""
        root, liveliness = keys.root, session.liveliness()
        tokens = [
            liveliness.declare_subscriber(
                selector, lambda s: self.note(f"token {str(s.kind).rsplit('.', 1)[-1]}", s)
            )
            for selector in (
                keys.all_workers(),
                keys.all_containers(),
                keys.all_providers(),
                f"{root}/data/**",  # the measured edges' (io.flowing)
            )
        ]
        return [
            *tokens,
            session.declare_subscriber(f"{root}/control/**", lambda s: self.note("control", s)),
            session.declare_subscriber(
                hand_over_key(keys.relation(C_A)),
                lambda s: self.note(f"hand-over {s.payload.to_bytes().decode()[:60]}", s),
            ),
            session.declare_subscriber(f"{root}/data/**", lambda s: self.note("data", s)),
            session.declare_subscriber(keys.relation(C_A), lambda s: self.note("relation", s)),
        ]

    def around(self, start_ns: int, end_ns: int) -> list[list[Any]]:
        """The items from ``start_ns`` to ``end_ns``: ms after ``start_ns``, what, key; of the
        data keys only the first and the last sample of each in the span, and the last before."""
        with self.lock:
            span = [i for i in self.items if start_ns <= i[0] < end_ns]
            before = {}
            for item in self.items:
                if item[1] == "data" and item[0] < start_ns:
                    before[item[2]] = item
        firsts: dict[str, tuple[int, str, str]] = {}
        lasts: dict[str, tuple[int, str, str]] = {}
        for item in span:
            if item[1] == "data":
                firsts.setdefault(item[2], item)
                lasts[item[2]] = item
        kept = [i for i in span if i[1] not in ("data", "relation")]
        relation = [i for i in span if i[1] == "relation"]
        for a, b in itertools.pairwise(relation):  # the samples either side of a gap
            if b[0] - a[0] > TRACED_GAP_MS * 1e6:
                kept += [(a[0], "relation before a gap", a[2]), (b[0], "relation after it", b[2])]
        kept += [(t, "last data before", k) for t, _, k in before.values()]
        kept += [(t, "first data", k) for t, _, k in firsts.values()]
        kept += [
            (t, "last data", k)
            for t, _, k in lasts.values()
            if (t, "data", k) not in firsts.values()
        ]
        return [[round((t - start_ns) / 1e6, 1), what, key] for t, what, key in sorted(kept)]


class FirstMeasurement:
    """While open, the arrival (wall clock ns) of the first sample on ``provider``'s data keys;
    :meth:`wait` returns it."""

    def __init__(self, session: Any, keys: KeySpace, provider: str) -> None:
        self._key = keys.data(provider) + "/*"
        self._session = session
        self._seen = threading.Event()
        self.at_ns = 0

    def _first(self, _sample: Any) -> None:
        if not self._seen.is_set():
            self.at_ns = time.time_ns()
            self._seen.set()

    def __enter__(self) -> FirstMeasurement:
        self._subscriber = self._session.declare_subscriber(self._key, self._first)
        return self

    def __exit__(self, *_: object) -> None:
        self._subscriber.undeclare()

    def wait(self, timeout: float) -> int:
        if not self._seen.wait(timeout):
            raise RuntimeError(f"no measurement on {self._key} within {timeout} s")
        return self.at_ns


def edge_name(key: Any) -> str:
    """``<provider>/<edge>`` of a measured edge's data key."""
    return "/".join(str(key).rsplit("/", 2)[-2:])


def truth_at(world: Any, at_ns: int) -> Any:
    rotation, translation = world.pose("C", "A", at_ns)
    return SimpleNamespace(rotation=rotation, translation=translation)


def judge(
    samples: list[tuple[int, int, Any, bool]], world: Any, since_ns: int | None = None
) -> dict[str, Any]:
    """Errors (mm, degrees), NEES and how many beyond 3 sigma, of the samples passed on; with
    ``since_ns`` (an event's time) also the first ten beyond 3 sigma: ms from the event to their
    stamp, mm, degrees and NEES."""
    passed = [s for _, _, s, on in samples if on]
    if not passed:
        return {"samples": 0}
    mm, deg = np.array([errors(s, world, s.timestamp_ns) for s in passed]).T
    values = [nees(s, truth_at(world, s.timestamp_ns)) for s in passed]
    judged = [v for v in values if v is not None]
    n = len(judged)
    beyond = [
        [round((s.timestamp_ns - since_ns) / 1e6, 1), round(a, 1), round(b, 2), round(v, 1)]
        for s, a, b, v in zip(passed, mm, deg, values, strict=True)
        if since_ns is not None and v is not None and v > THREE_SIGMA_NEES
    ]
    return {
        "samples": len(passed),
        "error_mm_max": float(mm.max()),
        "error_deg_max": float(deg.max()),
        "error_mm_p99": float(np.percentile(mm, 99)),
        "error_deg_p99": float(np.percentile(deg, 99)),
        "beyond_3_sigma": sum(v > THREE_SIGMA_NEES for v in judged),
        "without_covariance": len(values) - n,
        "nees_mean": float(np.mean(judged)) if judged else None,
        "nees_interval_95": [chi2.ppf(0.025, 6 * n) / n, chi2.ppf(0.975, 6 * n) / n] if n else None,
        **({"beyond_3_sigma_samples": beyond[:10]} if since_ns is not None else {}),
    }


def largest_gap_ms(arrivals: list[int]) -> float:
    return max((b - a for a, b in itertools.pairwise(arrivals)), default=0) / 1e6


def steady_gaps(stretches: list[list[tuple[int, int, Any, bool]]]) -> dict[str, float]:
    """The gaps between arrivals of samples passed on in a flow's steady state (ms): its p99
    and largest, the flow's own gaps to compare a switch's with, within each of its stretches
    (from one event to the next)."""
    gaps = [
        b - a
        for stretch in stretches
        for a, b in itertools.pairwise(sorted(arrived for arrived, _, _, on in stretch if on))
    ]
    if not gaps:
        return {}
    return {"gap_ms_p99": float(np.percentile(gaps, 99)) / 1e6, "gap_ms_max": max(gaps) / 1e6}


def kill_holder(session: Any, keys: KeySpace, patience_s: float = 5.0) -> int | None:
    """SIGKILL the process running the component that holds the relation key (the fusion's
    container: the derivation runs in one); when (ns), if one held it within ``patience_s``
    (none does while a claim is answered; the event's time: finding the process takes status
    queries, half a second on a loaded machine). The holder may be a component on standby
    (``agent.standby``): the flow that lost the better tracker runs on for ``STANDBY_S``
    beside the one chosen again and keeps the key, as certain as it (hand-over rule 6)."""
    deadline = time.monotonic() + patience_s
    seen: dict[str, Any] = {}
    while time.monotonic() < deadline:
        replies = fetch_latest(session, keys.agent_status(), timeout=1.0)
        agent = json.loads(replies[0]) if replies else {}
        producers = [i for i, c in agent.get("components", {}).items() if c["relations"]]
        for instance in producers + agent.get("standby_components", []):
            replies = fetch_latest(session, keys.status(instance), timeout=1.0)
            status = json.loads(replies[0]) if replies else None
            seen[instance] = status and {k: status.get(k) for k in ("pid", "holds")}
            if status and status.get("holds"):
                at = time.time_ns()
                os.kill(status["pid"], signal.SIGKILL)
                return at
        time.sleep(0.05)
    print(f"no holder within {patience_s} s; the candidates' statuses: {seen}", flush=True)
    return None


def host_managers(session: Any, keys: KeySpace) -> list[int]:
    """The pids of the host managers on the bench's network (the one its agent started). An
    agent stopped cleanly leaves its host manager serving its components for a successor
    (``ubitrack agent --help``): the bench stops it itself after the run, or the next run
    shares the machine with this one's idle flow for minutes."""
    pids = []
    for token in session.liveliness().get(keys.all_hosts(), timeout=2.0):
        if token.ok is None:
            continue
        name = str(token.ok.key_expr).rsplit("/", 1)[-1]
        request = encode_request(Status())
        for reply in session.get(keys.host_request(name), payload=request, timeout=2.0):
            if reply.ok is not None:
                pids.append(int(json.loads(reply.ok.payload.to_bytes())["pid"]))
    return pids


def stop_processes(pids: list[int], patience_s: float = 10.0) -> None:
    """SIGTERM each of ``pids`` (a host manager ends its workers then), SIGKILL after
    ``patience_s``."""
    for pid in pids:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGTERM)
    deadline = time.monotonic() + patience_s
    while pids and time.monotonic() < deadline:
        pids = [pid for pid in pids if Path(f"/proc/{pid}").exists()]
        time.sleep(0.1)
    for pid in pids:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)


def restart_agent(children: Processes, arguments: list[str], kill: bool) -> None:
    """The agent SIGKILLed (``kill``) or stopped cleanly (SIGTERM: it leaves its workers and
    host manager running), then started again at once."""
    agent = children.running.pop("agent")
    if kill:
        agent.kill()
    else:
        agent.terminate()
    agent.wait(timeout=30)
    children.start("agent", arguments)


def next_kind(
    rng: random.Random,
    running: frozenset[str],
    done: Counter,
    wanted: int,
    kinds: tuple[str, ...] = KINDS,
) -> str:
    """An event the state allows (:data:`ALLOWED`), drawn among the kinds done least so far;
    only ``kinds`` where the state allows one of them (else the way back, e.g. the A.R.T.
    tracker back after it went off, not counted towards ``wanted``)."""
    allowed = [k for k in ALLOWED[running] if k in kinds] or list(ALLOWED[running])
    fewest = min(done[k] for k in allowed)
    return rng.choice([k for k in allowed if done[k] == fewest and done[k] < wanted] or allowed)


def run(args: argparse.Namespace) -> dict[str, Any]:
    hub = own_network(args, "switch")
    member, keys = config.member_flags(hub), KeySpace(hub.key_prefix)
    rng = random.Random(args.seed)
    events: list[dict[str, Any]] = []
    wire, trace, children = Wire(), Trace(), Processes()
    withdrawn: Counter[str] = Counter()
    """How often each measured edge's token left (``io.flowing``): its sensor stopped, or a
    false alarm."""
    with tempfile.TemporaryDirectory() as scratch:
        live = args.calibration == "live"
        scenario, commands = demo_world(Path(scratch), args.seed, member, not live)
        commands |= better_tracker(Path(scratch), args.seed, member)

        def start(sensor: str) -> None:
            for name in PROCESSES[sensor]:
                children.start(name, commands[name])

        def stop(sensor: str) -> None:
            children.stop(*PROCESSES[sensor], at_once=args.sensor_stop == "together")

        agent = ["agent", "--quiet", "--replicas", str(args.replicas), *config.as_flags(hub)]
        managers: list[int] = []
        try:
            children.start("agent", agent)
            with (
                open_session(config.member_of(hub)) as session,
                Relation(  # asked before the sensors start
                    session, keys, C_A, application="switch-bench", keep_waiting=True
                ) as relation,
            ):
                watch = session.declare_subscriber(keys.relation(C_A), wire.take)
                edge_tokens = session.liveliness().declare_subscriber(
                    f"{keys.root}/data/**",
                    lambda s: str(s.kind) == PUT or withdrawn.update([edge_name(s.key_expr)]),
                )
                traced = trace.declare(session, keys) if args.trace else []
                children.start("sim database", commands["sim database"])
                if live:
                    children.start("store", commands["store"])
                start("camera")
                start("art")
                running = frozenset({"art", "camera"})
                relation.wait_for(timeout=90)
                calibration = calibrate(session, keys, scenario.world) if live else None
                wait_for_services(session, keys, present=True)
                wait_for_warm_pool(session, keys)
                managers = host_managers(session, keys)
                done: Counter = Counter()
                while any(done[k] < args.events for k in args.kinds):
                    kind = next_kind(rng, running, done, args.events, args.kinds)
                    before = FLOWS[running]
                    at = time.time_ns()
                    if kind == "worker killed":
                        # On a loaded machine the agent may have planned without a sensor
                        # whose data came late meanwhile: the fusion back first.
                        wait_for_services(session, keys, present=True)
                        killed = kill_holder(session, keys)
                        if killed is None:
                            raise RuntimeError("no component holds the relation key")
                        at = killed
                    elif kind.startswith("agent"):
                        restart_agent(children, agent, kind == "agent killed")
                    else:
                        sensor = next(v for k, v in SENSORS.items() if kind.startswith(k))
                        if kind.endswith(("off", "leaves")):
                            stop(sensor)
                            running = running - {sensor}
                        else:
                            with FirstMeasurement(session, keys, PROVIDERS[sensor]) as first:
                                start(sensor)
                                at = first.wait(SENSOR_START_S)
                            running = running | {sensor}
                    done[kind] += 1
                    wait_for_services(session, keys, present=len(running) >= 2)
                    time.sleep(rng.uniform(*args.dwell))
                    events.append({"kind": kind, "at_ns": at, "from": before, "to": FLOWS[running]})
                    print(f"{len(events):3d} {kind:13s} {before} -> {FLOWS[running]}", flush=True)
                for subscriber in [watch, edge_tokens, *traced]:
                    subscriber.undeclare()
                counters = dict(relation.counters)
        finally:
            children.stop_all()
            stop_processes(managers)
        result = summarise(events, wire, scenario, counters) | {
            "calibration": calibration,
            "edge_tokens_withdrawn": dict(sorted(withdrawn.items())),
        }
        if args.trace:  # up to the next event: the old flow is retired after the second
            ends = [e["at_ns"] for e in result["events"][1:]] + [time.time_ns()]
            for event, end in zip(result["events"], ends, strict=True):
                event["trace"] = trace.around(event["at_ns"] - int(BEFORE_S * 1e9), end)
        return result


CALIBRATION_TIMEOUT_S = 120.0
"""Longest the live calibration of ``C -> HT`` may take (the demo's default is 60 s; a
loaded machine takes longer)."""


def calibrate(session: Any, keys: KeySpace, world: Any) -> dict[str, Any]:
    """``C -> HT`` calibrated live and stored, the flow rewired onto it, as the demo does
    (:func:`ubitrack_agent.commands.demo.calibrate_live`); the demo's calibration line (its
    error against the truth, for printing only)."""
    lines: list[dict[str, Any]] = []

    def say(line: dict[str, Any], text: str) -> None:
        if line["event"] == "calibration":
            lines.append(line)
            print(text, flush=True)

    calibrate_live(session, keys, world, say, CALIBRATION_TIMEOUT_S)
    return lines[-1]


def better_tracker(scratch: Path, seed: int, member: list[str]) -> dict[str, list[str]]:
    """The ``ubitrack`` arguments of a second, better A.R.T.-like tracker (:data:`BETTER`,
    :data:`BETTER_NOISE`) that tracks the same bodies: its own scenario (the demo's world with
    its frame added, its tracker section instead of the A.R.T.'s), simulator and DTrack
    adapter (``sim better``, ``dtrack better``)."""
    document = yaml.safe_load(scenario_with_true_calibration(scratch).read_text())
    frame, placement = BETTER["frame"], {k: v for k, v in BETTER.items() if k != "frame"}
    document["frames"][frame] = {"parent": "ART", **placement}
    port = _free_port("udp")
    document["art"] |= {"provider": frame, "frame": frame, "port": port, "noise": BETTER_NOISE}
    path = scratch / "better_tracker.yaml"
    path.write_text(yaml.safe_dump(document))
    art = load_scenario(str(path)).art
    flag = ["--scenario", str(path)]
    return {
        "sim better": simulator_arguments(flag, port, seed + 2)["sim art"],
        "dtrack better": ["dtrack", "--quiet", *dtrack_flags(art, port), *member],
    }


def summarise(
    events: list[dict[str, Any]], wire: Wire, scenario: Any, counters: dict[str, int]
) -> dict[str, Any]:
    """Per event and per kind (module docstring), and each flow's steady state."""
    world = scenario.world
    faster_hz = max(scenario.art.rate, scenario.camera.rate)
    samples = sorted(wire.samples, key=lambda s: s[0])
    seen: set[int] = set()
    duplicates = []
    for arrived, stamp, _, _ in samples:
        if stamp in seen:
            duplicates.append(arrived)
        seen.add(stamp)
    ends = [e["at_ns"] for e in events[1:]] + [samples[-1][0] + 1 if samples else 0]
    steady: dict[str, list] = {flow: [] for flow in FLOWS.values()}
    stretches: dict[str, list[list]] = {flow: [] for flow in FLOWS.values()}
    window_mm: list[list[float]] = []  # per event, the errors of the samples passed on
    for event, end in zip(events, ends, strict=True):
        start = event["at_ns"]
        after = [s for s in samples if start <= s[1] < start + int(WINDOW_S * 1e9)]
        window_mm.append([errors(s, world, s.timestamp_ns)[0] for _, _, s, on in after if on])
        near = (start - BEFORE_S * 1e9, start + WINDOW_S * 1e9)
        arrivals = [s[0] for s in samples if near[0] <= s[0] < near[1] and s[3]]  # passed on
        event.update(judge(after, world, start))
        event["gap_ms"] = largest_gap_ms(arrivals)
        event["gap_frames"] = event["gap_ms"] / 1e3 * faster_hz
        # The old flow is retired, and relation routes move, HAND_OVER_HOLD_S after the new
        # one is alive: later than the second after the event, so looked for up to the next.
        event["gap_ms_until_next"] = largest_gap_ms(
            [s[0] for s in samples if near[0] <= s[0] < end and s[3]]
        )
        event["duplicates_until_next"] = sum(start <= d < end for d in duplicates)
        event["duplicates"] = sum(start <= d < start + WINDOW_S * 1e9 for d in duplicates)
        event["out_of_order"] = sum(not on for _, _, _, on in after)
        settled = [s for s in samples if start + STEADY_AFTER_S * 1e9 <= s[1] < end]
        steady[event["to"]] += settled
        stretches[event["to"]].append(settled)
        if settled:  # where the steady state's outliers lie, from the event before them
            settled_judged = judge(settled, world, start)
            event["steady_beyond_3_sigma_samples"] = settled_judged["beyond_3_sigma_samples"]
            event["steady_nees_mean"] = settled_judged["nees_mean"]
    steady_judged = {
        flow: judge(s, world)
        | steady_gaps(stretches[flow])
        | {
            "nees_over_stretches": nees_over_batches(
                [e.get("steady_nees_mean") for e in events if e["to"] == flow]
            )
        }
        for flow, s in steady.items()
    }
    for event, mm in zip(events, window_mm, strict=True):
        bound = max(steady_judged[f].get("error_mm_p99", 0) for f in (event["from"], event["to"]))
        event["beyond_steady_p99"] = sum(value > bound for value in mm)
    kinds = {}
    for kind in KINDS:
        every = [e for e in events if e["kind"] == kind]
        mine = [e for e in every if e.get("samples")]
        if not mine:
            continue
        bound = [
            max(steady_judged[f].get("error_mm_p99", 0) for f in (e["from"], e["to"])) for e in mine
        ]
        nees_values = [e["nees_mean"] * e["samples"] for e in mine if e["nees_mean"] is not None]
        n = sum(e["samples"] - e["without_covariance"] for e in mine)
        kinds[kind] = {
            "events": len(mine),
            "samples": sum(e["samples"] for e in mine),
            "error_mm_max": max(e["error_mm_max"] for e in mine),
            "error_deg_max": max(e["error_deg_max"] for e in mine),
            "events_worse_than_steady_p99": sum(
                e["error_mm_max"] > b for e, b in zip(mine, bound, strict=True)
            ),
            # samples beyond the larger steady p99, against the count a steady flow has there
            "samples_beyond_steady_p99": sum(e["beyond_steady_p99"] for e in mine),
            "steady_would_have_95": [
                int(binom.ppf(q, sum(e["samples"] for e in mine), STEADY_TAIL))
                for q in (0.025, 0.975)
            ],
            "beyond_3_sigma": sum(e["beyond_3_sigma"] for e in mine),
            "nees_mean": sum(nees_values) / n if n else None,
            "nees_interval_95": [chi2.ppf(0.025, 6 * n) / n, chi2.ppf(0.975, 6 * n) / n]
            if n
            else None,
            "nees_over_events": nees_over_batches([e["nees_mean"] for e in mine]),
            "gap_ms_max": max(e["gap_ms"] for e in mine),
            "gap_frames_max": max(e["gap_frames"] for e in mine),
            "gap_ms_median": float(np.median([e["gap_ms"] for e in mine])),
            # every event: one with no sample in the second after has its gap only here
            "events_without_samples": len(every) - len(mine),
            "gap_ms_until_next_max": max(e["gap_ms_until_next"] for e in every),
            "gap_ms_until_next_median": float(np.median([e["gap_ms_until_next"] for e in every])),
            "duplicates_until_next": sum(e["duplicates_until_next"] for e in every),
            "duplicates": sum(e["duplicates"] for e in mine),
            "out_of_order": sum(e["out_of_order"] for e in mine),
        }
    return {
        "faster_sensor_hz": faster_hz,
        "three_sigma_nees": THREE_SIGMA_NEES,
        "kinds": kinds,
        "steady": steady_judged,
        "relation_counters": counters,
        "wire_rejected": wire.rejected,
        "events": [{k: v for k, v in e.items()} for e in events],
    }


def interval_text(batches: dict[str, Any] | None) -> str:
    """``low-high`` of :func:`bench.synthetic.nees_over_batches`, ``-`` without two batches."""
    return "-" if batches is None else "{:.2f}-{:.2f}".format(*batches["interval_95"])


def print_tables(result: dict[str, Any]) -> None:
    print(
        "\n| event | events | samples in the second after | largest error mm / deg | events "
        "over the flows' steady p99 | beyond 3 sigma | mean NEES (95 % interval over events; "
        "as if independent samples) | largest gap "
        "ms (frames) | duplicates | out of order |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for kind, k in result["kinds"].items():
        interval, events = k["nees_interval_95"], k["nees_over_events"]
        nees_text = (
            f"{k['nees_mean']:.2f} ({interval_text(events)}; {interval[0]:.2f}-{interval[1]:.2f})"
            if k["nees_mean"] is not None
            else "-"
        )
        print(
            f"| {kind} | {k['events']} | {k['samples']} | {k['error_mm_max']:.1f} / "
            f"{k['error_deg_max']:.2f} | {k['events_worse_than_steady_p99']} | "
            f"{k['beyond_3_sigma']} | {nees_text} | {k['gap_ms_max']:.0f} "
            f"({k['gap_frames_max']:.1f}) | {k['duplicates']} | {k['out_of_order']} |"
        )
    print(
        "\n| event | samples in the second after | beyond the larger steady p99 | a steady "
        "flow's 95 % range |"
    )
    print("|---|---|---|---|")
    for kind, k in result["kinds"].items():
        low, high = k["steady_would_have_95"]
        print(f"| {kind} | {k['samples']} | {k['samples_beyond_steady_p99']} | {low}-{high} |")
    print(
        "\n| event | largest gap ms in the second after: median / largest | until the next "
        "event (every event): median / largest | events without a sample in the second after | "
        "duplicates until the next |"
    )
    print("|---|---|---|---|---|")
    for kind, k in result["kinds"].items():
        print(
            f"| {kind} | {k['gap_ms_median']:.0f} / {k['gap_ms_max']:.0f} | "
            f"{k['gap_ms_until_next_median']:.0f} / {k['gap_ms_until_next_max']:.0f} | "
            f"{k['events_without_samples']} | {k['duplicates_until_next']} |"
        )
    print(
        "\n| steady state | samples | p99 error mm / deg | largest mm / deg | mean NEES (95 % "
        "interval over stretches) | gap ms "
        "p99 / largest |"
    )
    print("|---|---|---|---|---|---|")
    for flow, s in result["steady"].items():
        if not s.get("samples"):
            continue
        mean = (
            f"{s['nees_mean']:.2f} ({interval_text(s.get('nees_over_stretches'))})"
            if s["nees_mean"] is not None
            else "-"
        )
        print(
            f"| {flow} | {s['samples']} | {s['error_mm_p99']:.1f} / {s['error_deg_p99']:.2f} | "
            f"{s['error_mm_max']:.1f} / {s['error_deg_max']:.2f} | {mean} | "
            f"{s.get('gap_ms_p99', 0):.0f} / {s.get('gap_ms_max', 0):.0f} |"
        )
    withdrawn = result.get("edge_tokens_withdrawn", {})
    counts = ", ".join(f"{edge} {count}" for edge, count in withdrawn.items())
    print(f"\nedge tokens withdrawn (io.flowing): {counts or 'none'}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=20, help="events of each kind")
    parser.add_argument("--seed", type=int, default=7, help="the events' order and the noise")
    parser.add_argument(
        "--dwell",
        type=lambda text: tuple(float(x) for x in text.split(",")),
        default=(2.0, 4.0),
        help="seconds between one event's settled flow and the next event, drawn in LO,HI",
    )
    parser.add_argument(
        "--kinds",
        type=lambda text: tuple(k.strip() for k in text.split(";")),
        default=KINDS,
        help="only these kinds of event, ';'-separated (and the ways back they need, not "
        f"counted); default all: {'; '.join(KINDS)}",
    )
    parser.add_argument(
        "--replicas", type=int, default=0, help="the agent's --replicas (default: %(default)s)"
    )
    parser.add_argument(
        "--sensor-stop",
        choices=("in-turn", "together"),
        default="in-turn",
        help="a sensor off: its simulator stopped, then its adapter once the simulator has "
        "ended (the tracker silent first, its provider gone 0.1-0.3 s later), or both at once "
        "(the provider gone as the data stops) (default: %(default)s)",
    )
    parser.add_argument(
        "--calibration",
        choices=("live", "true"),
        default="live",
        help="C -> HT calibrated live first, as the demo does, or served from the scenario's "
        "truth (default: %(default)s)",
    )
    parser.add_argument(
        "--trace",
        action="store_true",
        help="record tokens, control commands, hand-over messages and inputs from each event to "
        "the next (each event's 'trace' in the results)",
    )
    parser.add_argument(
        "--output", type=Path, default=RESULTS, help=f"JSON file (default {RESULTS.name} there)"
    )
    config.add_arguments(parser)
    args = parser.parse_args(argv)
    if unknown := set(args.kinds) - set(KINDS):
        parser.error(f"unknown kinds {sorted(unknown)}; known: {'; '.join(KINDS)}")
    result = run(args)
    print_tables(result)
    args.output.parent.mkdir(exist_ok=True)
    dwell = ",".join(f"{d:g}" for d in args.dwell)
    args.output.write_text(
        json.dumps(
            {
                "command": f"python -m bench.switch_bench --events {args.events} --seed "
                f"{args.seed} --dwell {dwell}"
                + (f" --kinds '{';'.join(args.kinds)}'" if args.kinds != KINDS else "")
                + (f" --replicas {args.replicas}" if args.replicas else "")
                + (" --calibration true" if args.calibration == "true" else "")
                + (" --sensor-stop together" if args.sensor_stop == "together" else "")
                + (" --trace" if args.trace else "")
                + (f" --output {args.output}" if args.output != RESULTS else ""),
                "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                "machine": {"python": platform.python_version(), "cpus": os.cpu_count()},
                "load_average_end": os.getloadavg(),
                **result,
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
