"""Fuzz benchmark (issue 11, item 2, the long version of ``tests/integration/test_fuzz_*.py``).

Run: ``python -m bench.fuzz_bench [--seconds N] [--seed S]``. A live agent (with its host
manager, warm pool and workers) serves ``WT->HT`` fused from two exact trackers
(``ubitrack_agent.sim_trackers.exact_tracker``) to an application, all on loopback. For
``--seconds`` the bench then drives every network entry point with hostile input drawn by the fuzz
tests' hypothesis strategies (``tests/integration/fuzz_inputs.py``), seeded with ``--seed``: on the
agent's side liveliness tokens of every kind, query keys, provider fragments, host exit reports and
status queries; on the workers' side measurements on the keys the live workers read, control
commands to them, specifications to the idle pool members and requests to the host manager.

Afterwards it records, printed and in ``bench/results/fuzz.json``: messages sent per kind and
the time each send took, the processes that died (agent, host manager, workers), the counters
that moved (agent status, host manager status, worker statuses: the rejections among them),
the resident memory of the agent, the host manager and the workers before and after, and
whether the application's relation is still correct against the trackers' truth (as
``test_agent.assert_true_pose``: within 3 mm)."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import hypothesis
import numpy as np
import zenoh
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from bench.report import write_results
from tests.integration import fuzz_inputs as fuzz
from tests.integration.conftest import end_groups
from tests.integration.test_agent import WT_HT, Setup, fresh_samples, opened
from tests.integration.test_host import relay
from tests.integration.zenoh_helpers import wait_until
from ubitrack_agent.core import se3
from ubitrack_agent.io.application import Relation
from ubitrack_agent.net.host_protocol import Status, encode_request
from ubitrack_agent.net.keys import Token
from ubitrack_agent.sim_trackers.exact_tracker import true_wt_ht

RESULTS = Path(__file__).with_name("results") / "fuzz.json"
BATCH = 50
"""Examples per hypothesis run; runs follow each other, seeded ``seed``, ``seed + 1``, ...,
until the time is up."""
LIVE_TOKENS = 200
"""Hostile tokens kept declared at once; older ones are undeclared (DELETE events)."""
TRUE_WITHIN_M = 3e-3
"""The tolerance of ``test_agent.assert_true_pose`` (fusing unsynchronised trackers)."""
CHECK_SAMPLES = 50
Sender = Callable[[st.DataObject], None]


@dataclass
class System:
    """The live system under fuzzing and what the senders need of it."""

    setup: Setup
    agent: Any
    host: str
    inputs: list[str]
    """Keys the live workers read (measurements are sent there)."""
    instances: list[str]
    server: fuzz.FragmentServer
    tokens: deque = field(default_factory=deque)
    providers: int = 0


@dataclass
class Tally:
    """Messages sent per kind, refused locally by zenoh (a key it does not take), and time."""

    sent: Counter = field(default_factory=Counter)
    refused: Counter = field(default_factory=Counter)
    seconds: Counter = field(default_factory=Counter)


def start(setup: Setup) -> tuple[Any, Relation]:
    """The agent, two trackers fused into ``WT->HT`` and an application receiving it."""
    agent = setup.start_agent()
    setup.tracker("art", "ART", 30.0, 2.0)
    setup.tracker("ir", "IR", 100.0, -1.0)
    relation = Relation(setup.session, setup.keys, WT_HT, application="fuzz-bench")
    wait_until(lambda: "fusion" in setup.alive_services().values(), timeout=60)
    fresh_samples(relation, 10, timeout=30)
    return agent, relation


def steady(setup: Setup, relation: Relation) -> str:
    """Wait until the host manager's warm pool is full (its imports no longer compete for the
    CPUs) and the relation flows; the host manager's name."""
    host = wait_until(lambda: setup.status()["hosts"], timeout=30)[0]
    wait_until(lambda: (s := ask_host(setup, host)) and s["pool_ready"] >= s["pool_size"], 180)
    fresh_samples(relation, 10, timeout=30)
    return host


def ask_host(setup: Setup, host: str) -> dict:
    """The host manager's status (``{}`` without an answer)."""
    request = encode_request(Status())
    replies = list(setup.session.get(setup.keys.host_request(host), payload=request, timeout=5.0))
    ok = [reply.ok for reply in replies if reply.ok is not None]
    return json.loads(ok[0].payload.to_bytes()) if ok else {}


def worker_status(setup: Setup, instance: str) -> dict:
    """A worker's status (``{}`` without an answer)."""
    replies = list(setup.session.get(setup.keys.status(instance), timeout=2.0))
    ok = [reply.ok for reply in replies if reply.ok is not None]
    return json.loads(ok[0].payload.to_bytes()) if ok else {}


def rss(pid: int) -> float | None:
    """Resident memory in MB, ``None`` for a process that is gone."""
    try:
        return round(fuzz.rss_mb(pid), 1)
    except (FileNotFoundError, ProcessLookupError):
        return None


def snapshot(system: System) -> dict[str, Any]:
    """Pids, counters and memory of the agent, the host manager and every worker."""
    host = ask_host(system.setup, system.host)
    workers = {name: worker_status(system.setup, name) for name in host.get("instances", {})}
    return {
        "agent": {
            "pid": system.agent.pid,
            "rss_mb": rss(system.agent.pid),
            "counters": system.setup.status()["counters"],
        },
        "host": {"pid": host["pid"], "rss_mb": rss(host["pid"]), "counters": host["counters"]},
        "workers": {
            name: {
                "pid": status["pid"],
                "rss_mb": rss(status["pid"]),
                "counters": status["counters"],
                "pool": status.get("pool", {}),
            }
            for name, status in workers.items()
            if status
        },
    }


def idle_pool_members(setup: Setup) -> list[str]:
    """The ids of the pool members waiting for a specification (not the bench's own hostile
    pool tokens)."""
    replies = setup.session.liveliness().get(setup.keys.all_pools(), timeout=1.0)
    tokens = [setup.keys.parse_token("pool", str(r.ok.key_expr)) for r in replies if r.ok]
    return sorted(token.name for token in tokens if isinstance(token, Token))


def declare(system: System, key: str) -> None:
    """A hostile liveliness token; the oldest beyond ``LIVE_TOKENS`` is undeclared."""
    system.tokens.append(system.setup.session.liveliness().declare_token(key))
    if len(system.tokens) > LIVE_TOKENS:
        system.tokens.popleft().undeclare()


def agent_senders(system: System) -> dict[str, Sender]:
    """Hostile input for each entry point of the agent."""
    keys, session, root = system.setup.keys, system.setup.session, system.setup.keys.root

    def token(data: st.DataObject) -> None:
        declare(system, f"{root}/{data.draw(fuzz.TOKEN_KINDS)}/{data.draw(fuzz.HOSTILE_NAMES)}")

    def query(data: st.DataObject) -> None:
        declare(system, f"{root}/query/{'/'.join(data.draw(fuzz.QUERY_CHUNKS))}")

    def fragment(data: st.DataObject) -> None:
        name = f"fz-{system.providers}"  # a fresh provider for every example
        system.providers += 1
        system.server.payloads[name] = data.draw(fuzz.hostile_fragment(name))
        declare(system, keys.provider(name))

    def exit_report(data: st.DataObject) -> None:
        host, payload = data.draw(fuzz.EXIT_REPORT_HOSTS), data.draw(fuzz.EXIT_REPORT_PAYLOADS)
        session.put(f"{root}/host/{host}/exited", payload)  # hostile names: no KeySpace check

    def status_query(data: st.DataObject) -> None:
        parameters = data.draw(fuzz.STATUS_PARAMETERS)
        payload = data.draw(fuzz.STATUS_PAYLOADS)
        list(session.get(f"{keys.agent_status()}?{parameters}", payload=payload, timeout=0.2))

    return {
        "token": token,
        "query": query,
        "fragment": fragment,
        "exit_report": exit_report,
        "status_query": status_query,
    }


def worker_senders(system: System) -> dict[str, Sender]:
    """Hostile input for each entry point of the workers, the pool and the host manager."""
    keys, session = system.setup.keys, system.setup.session
    never_run = relay(keys, "fz-never")  # the base of hostile specifications and requests
    pool = idle_pool_members(system.setup)

    def measurement(data: st.DataObject) -> None:
        session.put(data.draw(st.sampled_from(system.inputs)), data.draw(fuzz.measurement_payloads))

    def control(data: st.DataObject) -> None:
        instance = data.draw(st.sampled_from(system.instances))
        session.put(keys.control(instance), data.draw(fuzz.control_commands()))

    def specification(data: st.DataObject) -> None:
        member = data.draw(st.sampled_from(pool))
        session.put(keys.pool(member), data.draw(fuzz.pool_specifications(never_run)))

    def host_request(data: st.DataObject) -> None:
        payload = data.draw(fuzz.host_requests(never_run))
        list(session.get(keys.host_request(system.host), payload=payload, timeout=5.0))

    senders = {"measurement": measurement, "control": control, "host_request": host_request}
    return senders | ({"pool_specification": specification} if pool else {})


def run_batch(senders: dict[str, Sender], seed: int, tally: Tally) -> None:
    """One seeded hypothesis run of ``BATCH`` examples, each a message of a drawn kind (whole
    runs only: hypothesis requires each example to draw the same way when replayed)."""

    @hypothesis.seed(seed)
    @settings(
        max_examples=BATCH,
        deadline=None,
        database=None,
        phases=[Phase.generate],
        suppress_health_check=list(HealthCheck),
    )
    @given(st.sampled_from(sorted(senders)), st.data())
    def one(kind: str, data: st.DataObject) -> None:
        began = time.perf_counter()
        try:
            senders[kind](data)
            tally.sent[kind] += 1
        except zenoh.ZError:
            tally.refused[kind] += 1  # not a key zenoh takes: nothing reached the system
        tally.seconds[kind] += time.perf_counter() - began

    one()


def drive(system: System, seconds: float, seed: int) -> Tally:
    """Hostile messages of every kind for ``seconds`` (rounded up to whole batches)."""
    tally = Tally()
    deadline = time.monotonic() + seconds
    batch = 0
    while time.monotonic() < deadline:
        senders = agent_senders(system) | worker_senders(system)
        run_batch(senders, seed + batch, tally)
        batch += 1
    return tally


def relation_check(relation: Relation) -> dict[str, Any]:
    """The application's newest samples against the trackers' truth: the largest difference of
    any element of the pose matrices, the measure of ``test_agent.assert_true_pose``."""
    try:
        samples = fresh_samples(relation, CHECK_SAMPLES, timeout=20)
    except TimeoutError:
        return {"samples": 0, "correct": False}
    errors = [
        np.abs(
            se3.to_matrix(s.rotation, s.translation) - se3.to_matrix(*true_wt_ht(s.timestamp_ns))
        ).max()
        for s in samples
    ]
    worst = float(max(errors))
    return {"samples": len(samples), "max_matrix_error": worst, "correct": worst <= TRUE_WITHIN_M}


def moved(before: dict[str, int], after: dict[str, int]) -> dict[str, int]:
    """The counters that changed, by how much."""
    return {k: v - before.get(k, 0) for k, v in sorted(after.items()) if v != before.get(k, 0)}


def summed(workers: dict[str, dict], part: str) -> Counter:
    """The workers' counters (or their pool processes' counters) added up."""
    total: Counter = Counter()
    for worker in workers.values():
        total.update(worker[part])
    return total


def alive(pid: int) -> bool:
    return Path(f"/proc/{pid}").exists()


def crashes(before: dict[str, Any]) -> list[str]:
    """The processes of the ``before`` snapshot that are gone."""
    processes = {"agent": before["agent"]["pid"], "host": before["host"]["pid"]}
    processes |= {f"worker {n}": w["pid"] for n, w in before["workers"].items()}
    return [f"{name} (pid {pid})" for name, pid in processes.items() if not alive(pid)]


def report(
    tally: Tally, seconds: float, before: dict, after: dict, truth: dict[str, Any]
) -> dict[str, Any]:
    """The figures of one run."""
    total = sum(tally.sent.values()) + sum(tally.refused.values())
    return {
        "messages": dict(sorted(tally.sent.items())),
        "refused_by_zenoh": dict(sorted(tally.refused.items())),
        "messages_total": total,
        "ms_per_message": round(1e3 * seconds / max(total, 1), 3),
        "ms_per_message_by_kind": {
            kind: round(1e3 * spent / (tally.sent[kind] + tally.refused[kind]), 3)
            for kind, spent in sorted(tally.seconds.items())
        },
        "crashes": crashes(before),
        "counters_moved": {
            "agent": moved(before["agent"]["counters"], after["agent"]["counters"]),
            "host": moved(before["host"]["counters"], after["host"]["counters"]),
            "workers": moved(
                summed(before["workers"], "counters"), summed(after["workers"], "counters")
            ),
            "pool_processes": moved(
                summed(before["workers"], "pool"), summed(after["workers"], "pool")
            ),
        },
        "rss_mb": {
            "agent": [before["agent"]["rss_mb"], after["agent"]["rss_mb"]],
            "host": [before["host"]["rss_mb"], after["host"]["rss_mb"]],
            "workers": {
                name: [worker["rss_mb"], after["workers"].get(name, {}).get("rss_mb")]
                for name, worker in before["workers"].items()
            },
        },
        "relation_after": truth,
    }


def run(seconds: float, seed: int) -> dict[str, Any]:
    """Start the system, fuzz it for ``seconds``, and measure it before and after."""
    processes: list = []
    try:
        with contextlib.contextmanager(opened)(processes) as setup:
            agent, relation = start(setup)
            host = steady(setup, relation)
            status = setup.status()
            system = System(
                setup=setup,
                agent=agent,
                host=host,
                inputs=sorted(
                    {b["key"] for c in status["components"].values() for b in c["inputs"]}
                ),
                instances=sorted(status["components"]),
                server=fuzz.FragmentServer(setup.session, setup.keys),
            )
            before = snapshot(system)
            began = time.monotonic()
            tally = drive(system, seconds, seed)
            elapsed = time.monotonic() - began
            for token in system.tokens:
                token.undeclare()
            truth = relation_check(relation)
            after = snapshot(system)
            relation.close()
            system.server.close()
            return report(tally, elapsed, before, after, truth)
    finally:
        end_groups(processes)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.fuzz_bench", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--seconds", type=float, default=60.0, help="fuzzing time (default 60)")
    parser.add_argument("--seed", type=int, default=11, help="hypothesis seed (default 11)")
    args = parser.parse_args(argv)
    results = {
        "command": f"python -m bench.fuzz_bench --seconds {args.seconds:g} --seed {args.seed}",
        "date": datetime.now(UTC).strftime("%Y-%m-%d"),
        "machine": f"{os.cpu_count()} CPU, Python {platform.python_version()}",
        **run(args.seconds, args.seed),
    }
    write_results(RESULTS, results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
