"""One active agent per domain (issue 11, item 5), with real agents, workers and trackers.

Two agents start together on one domain: one becomes active, the other a standby that changes
nothing. The active one is SIGKILLed while an application listens: the standby takes over and
adopts every worker (same processes, none started twice), and the application's stream has no
gap longer than the whole takeover took (up to the host manager answering it: the one the
killed agent started, which outlives it and which it adopts) and no sample twice. The killed
agent, started again, stands by; a clean stop of the active agent then hands over to it, again
without stopping a worker.
"""

from __future__ import annotations

import itertools
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator

import pytest

from tests.integration.chaos_faults import host_status, incarnations
from tests.integration.test_agent import WT_HT, Setup, assert_true_pose, fresh_samples, opened
from tests.integration.zenoh_helpers import free_port, wait_until
from ubitrack_agent.io.application import Relation
from ubitrack_agent.net.transport import fetch_latest

pytestmark = pytest.mark.integration


@pytest.fixture
def setup(processes) -> Iterator[Setup]:
    yield from opened(processes)


class Stream:
    """Arrival times of every sample the application receives."""

    def __init__(self) -> None:
        self.arrivals: list[float] = []
        self._lock = threading.Lock()

    def __call__(self, sample) -> None:
        with self._lock:
            self.arrivals.append(time.monotonic())

    def between(self, start: float, end: float) -> list[float]:
        with self._lock:
            return [at for at in self.arrivals if start <= at <= end]


def agent_command(setup: Setup, listen: int, connect: int | None) -> list[str]:
    return [
        sys.executable,
        "-m",
        "ubitrack_agent.cli",
        "--log-level",
        "INFO",
        "agent",
        "--pool-size",
        "2",
        "--listen",
        f"tcp/127.0.0.1:{listen}",
        *(["--connect", f"tcp/127.0.0.1:{connect}"] if connect else []),
        "--domain",
        setup.domain,
    ]


def agent_statuses(setup: Setup) -> dict[str, dict]:
    """Every agent's status, active or standby, by id."""
    replies = fetch_latest(setup.session, setup.keys.all_agent_statuses(), timeout=0.5)
    statuses = [json.loads(reply) for reply in replies]
    return {status["agent"]["id"]: status for status in statuses if status.get("agent")}


def by_pid(setup: Setup) -> dict[int, dict]:
    """Every agent's status, by the pid in its id."""
    return {int(agent.split(".")[1]): status for agent, status in agent_statuses(setup).items()}


def roles(setup: Setup) -> dict[int, str]:
    """Each agent's role, by the pid in its id."""
    return {pid: status["agent"]["role"] for pid, status in by_pid(setup).items()}


def known_pids(setup: Setup, instances: set[str]) -> dict[str, int] | None:
    """Each instance's worker pid, once every one has answered (a status query may time out
    on a loaded machine, and a missing pid is no evidence of anything)."""
    pids = {instance: setup.worker_pid(instance) for instance in instances}
    return pids if None not in pids.values() else None


def one_active_one_standby(setup: Setup) -> dict[int, str] | None:
    """The agents' roles by pid, once one is active and one stands by."""
    seen = roles(setup)
    return seen if sorted(seen.values()) == ["active", "standby"] else None


def all_alive(setup: Setup) -> set[str] | None:
    """Every component the active agent wants, once all are alive (and fusion among them)."""
    status = setup.status()
    alive = set(setup.alive_services())
    wanted = set(status["components"]) if status else set()
    fused = (
        any(c["service"] == "fusion" for c in status["components"].values()) if status else False
    )
    return alive if fused and alive == wanted else None


def host_pid(setup: Setup) -> int | None:
    """The pid of the host manager the active agent sees (one, named after the machine)."""
    status = host_status(setup)
    return status["pid"] if status else None


def adopted_by(setup: Setup, pid: int, instances: set[str], old_host: int | None) -> bool:
    """The agent ``pid`` is active, runs exactly ``instances``, all alive, and the host
    manager ``old_host`` answers it, ready to start what may end (the killed agent's, which
    outlives it: adopted, not started again): the whole takeover."""
    status = setup.status()
    return (
        status is not None
        and status["agent"]["id"].endswith(f".{pid}")
        and set(setup.alive_services()) == instances
        and not status["unsolved"]
        and host_pid(setup) == old_host
    )


def test_a_standby_takes_over_without_gap_or_duplicate_and_a_clean_stop_hands_over(
    setup, processes
):
    ports = (setup.port, free_port())
    agents = [
        subprocess.Popen(agent_command(setup, ports[0], None), start_new_session=True),
        subprocess.Popen(agent_command(setup, ports[1], ports[0]), start_new_session=True),
    ]
    processes.extend(agents)
    setup.tracker("art", "ART", 30.0, 2.0)
    setup.tracker("cam", "CAM", -20.0, 1.5)
    stream = Stream()
    relation = Relation(setup.session, setup.keys, WT_HT, application="app", callback=stream)
    wait_until(lambda: relation.latest() is not None, timeout=30)
    seen = wait_until(lambda: one_active_one_standby(setup), timeout=10)
    active = next(p for p in agents if seen[p.pid] == "active")
    standby = next(p for p in agents if p is not active)
    instances = wait_until(lambda: all_alive(setup), timeout=30)
    pids = wait_until(lambda: known_pids(setup, instances), timeout=10)
    # The standby plans what runs (its plan follows the worker tokens)...
    wait_until(lambda: set(by_pid(setup)[standby.pid]["components"]) == instances, timeout=10)
    standby_counters = by_pid(setup)[standby.pid]["counters"]
    for counter in ("adopted", "reconfigurations", "orphans_stopped", "stops_resent"):
        assert counter not in standby_counters  # ...but changes nothing

    before = stream.between(time.monotonic() - 3.0, time.monotonic())
    usual = max(b - a for a, b in itertools.pairwise(before))
    old_host = host_pid(setup)
    out_of_order = relation.counters["out_of_order"]  # the flow may have changed at the start
    killed_at = time.monotonic()
    os.kill(active.pid, signal.SIGKILL)
    active.wait()
    wait_until(lambda: adopted_by(setup, standby.pid, instances, old_host), timeout=20)
    took_over = time.monotonic() - killed_at
    assert setup.status()["counters"]["adopted"] == len(instances)
    assert {i: setup.worker_pid(i) for i in instances} == pids  # adopted, not restarted
    assert all(len(seen) == 1 for seen in incarnations(setup).values())
    for sample in fresh_samples(relation, 10):
        assert_true_pose(sample)
    during = stream.between(killed_at - 0.5, killed_at + took_over + 0.5)
    gaps = [b - a for a, b in itertools.pairwise(during)]
    # A sample due as the takeover began is late by at most the takeover and its usual jitter.
    assert during and max(gaps) <= took_over + usual, (max(gaps), took_over, usual)
    # The takeover changes no worker: no sample of the stream comes out of time order (the
    # relation passes on none such, but counts them) and none too old to keep.
    assert relation.counters["out_of_order"] == out_of_order
    assert relation.counters["dropped_stale"] == 0

    own, other = (0, 1) if active is agents[0] else (1, 0)
    command = agent_command(setup, ports[own], ports[other])
    restarted = subprocess.Popen(command, start_new_session=True)
    processes.append(restarted)
    wait_until(lambda: roles(setup).get(restarted.pid) == "standby", timeout=20)
    time.sleep(2.5)  # longer than its settling and orphan grace: it must still change nothing
    assert roles(setup) == {standby.pid: "active", restarted.pid: "standby"}
    assert {i: setup.worker_pid(i) for i in instances} == pids

    old_host = host_pid(setup)
    standby.send_signal(signal.SIGTERM)  # a clean stop with a standby alive hands over
    assert standby.wait(timeout=15) == 0
    wait_until(lambda: adopted_by(setup, restarted.pid, instances, old_host), timeout=20)
    assert {i: setup.worker_pid(i) for i in instances} == pids
    for sample in fresh_samples(relation, 10):
        assert_true_pose(sample)

    relation.close()  # the active agent stops what nothing wants any more
    wait_until(lambda: not incarnations(setup), timeout=15)
