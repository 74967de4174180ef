"""Chaos without orphans (issue 11, item 3): a seeded run of random faults against a live
agent, its host manager, two noise-free trackers and applications listening, then checks
that the system is whole again within ``RECOVERY_S``.

Faults, drawn from ``random.Random(SEED)`` (``UBITRACK_CHAOS_SEED`` overrides it):

* a tracker killed (SIGKILL or SIGTERM) and started again;
* a worker killed (SIGKILL or SIGTERM; the agent starts it again);
* the agent killed (SIGKILL: its workers keep running and the restarted agent adopts them;
  or SIGTERM: a clean stop ends every worker) and started again;
* a flapping application: a query opened and closed again within 0.05-0.4 s, so workers are
  told to stop while they are starting.

After the faults every process is back and the checks must hold within ``RECOVERY_S``: every
application receives fresh samples equal to the trackers' known truth, each wanted component
runs in exactly one process (one token incarnation, one status pid), no worker runs that
nothing wants, and every worker process of the domain (``ps``) is either a wanted
component's or an idle member the host manager counts in its pool: none leaked. Every
process is killed at the end, pass or fail (the ``processes`` fixture and ``kill_tagged``).
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import time
from collections.abc import Iterator
from types import SimpleNamespace

import pytest

from tests.integration.conftest import kill_tagged
from tests.integration.test_agent import Setup, assert_true_pose, fresh_samples
from tests.integration.zenoh_helpers import free_port, wait_until
from ubitrack_agent.core import ErrorPose, se3
from ubitrack_agent.io.application import Relation
from ubitrack_agent.net import config
from ubitrack_agent.net.host_protocol import Status, encode_request
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.session import open_session

pytestmark = pytest.mark.integration

SEED = int(os.environ.get("UBITRACK_CHAOS_SEED", "11"))
EVENTS = 14
"""Faults per run, one every 1.0-2.5 s: each kind three times, two more at random."""
RECOVERY_S = 40.0
"""After the last fault, the time within which every check must hold (typically 5-15 s: up
to ten workers may have to start cold on a loaded machine)."""
POOL_SIZE = 3
WT_HT = RelationId("WT", "HT", "6D")
HT_WT = RelationId("HT", "WT", "6D")
FLAPPING = RelationId("HT", "ART", "6D")
TRACKERS = {"art": ("ART", 30.0, 2.0), "ir": ("IR", 100.0, -1.0)}


class Chaos:
    """The system under faults: the processes it runs, and the faults."""

    def __init__(self, setup: Setup, rng: random.Random) -> None:
        self.setup = setup
        self.rng = rng
        self.agent = self.start_agent(wait=True)
        self.trackers = {name: self.start_tracker(name) for name in TRACKERS}
        self.log: list[str] = []

    def start_agent(self, wait: bool = False) -> subprocess.Popen:
        """The agent; a restart does not wait for it (the faults go on meanwhile)."""
        return self.setup.start_agent("--pool-size", str(POOL_SIZE), wait=wait)

    def start_tracker(self, name: str) -> subprocess.Popen:
        return self.setup.tracker(name, *TRACKERS[name])

    def signal(self) -> signal.Signals:
        return self.rng.choice([signal.SIGKILL, signal.SIGTERM])

    def kill_tracker(self) -> None:
        name = self.rng.choice(sorted(TRACKERS))
        how = self.signal()
        self.trackers[name].send_signal(how)
        self.trackers[name].wait()
        time.sleep(self.rng.uniform(0.0, 1.5))
        self.trackers[name] = self.start_tracker(name)
        self.log.append(f"tracker {name} {how.name}")

    def kill_worker(self) -> None:
        alive = sorted((self.setup.status() or {"components": {}})["components"])
        pids = {pid for instance in alive for pid in worker_pids(self.setup, instance)}
        if not pids:
            return
        pid, how = self.rng.choice(sorted(pids)), self.signal()
        try:
            os.kill(pid, how)
        except ProcessLookupError:
            return
        self.log.append(f"worker {pid} {how.name}")

    def kill_agent(self) -> None:
        how = self.signal()
        self.agent.send_signal(how)
        self.agent.wait()
        self.agent = self.start_agent()
        self.log.append(f"agent {how.name}")

    def flap_application(self) -> None:
        relation = Relation(self.setup.session, self.setup.keys, FLAPPING, application="flap")
        time.sleep(self.rng.uniform(0.05, 0.4))
        relation.close()
        self.log.append("flapping application")

    def run(self, events: int) -> None:
        """``events`` faults, each kind at least ``events // 4`` times, in a seeded order."""
        kinds = [self.kill_tracker, self.kill_worker, self.kill_agent, self.flap_application]
        faults = kinds * (events // len(kinds))
        faults += [self.rng.choice(kinds) for _ in range(events - len(faults))]
        self.rng.shuffle(faults)
        for fault in faults:
            fault()
            time.sleep(self.rng.uniform(1.0, 2.5))


def worker_pids(setup: Setup, instance: str) -> set[int]:
    """The pids answering ``instance``'s status (one per process running it)."""
    replies = setup.session.get(setup.keys.status(instance), timeout=0.5)
    return {json.loads(r.ok.payload.to_bytes())["pid"] for r in replies if r.ok is not None}


def incarnations(setup: Setup) -> dict[str, list[str]]:
    """The worker token incarnations alive now, by instance."""
    found: dict[str, list[str]] = {}
    for reply in setup.session.liveliness().get(setup.keys.all_workers(), timeout=0.5):
        if reply.ok is not None:
            instance, incarnation = setup.keys.parse_worker(str(reply.ok.key_expr))
            found.setdefault(instance, []).append(incarnation)
    return found


def host_status(setup: Setup) -> dict | None:
    """The agent's host manager's status (it is named after the machine)."""
    status = setup.status()
    if not status or len(status["hosts"]) != 1:
        return None
    key = setup.keys.host_request(status["hosts"][0])
    replies = list(setup.session.get(key, payload=encode_request(Status()), timeout=1.0))
    ok = [r.ok for r in replies if r.ok is not None]
    return json.loads(ok[0].payload.to_bytes()) if ok else None


def worker_processes(domain: str) -> set[int]:
    """Every worker process of the test's domain, from ``ps``."""
    command = ["ps", "-ww", "-eo", "pid=,args="]  # -ww: whole lines, whatever COLUMNS says
    lines = subprocess.run(command, capture_output=True, text=True).stdout
    return {
        int(line.split()[0])
        for line in lines.splitlines()
        if "services.worker" in line and domain in line
    }


def whole(setup: Setup) -> str | None:
    """None if the system is whole, else what is wrong (see the module docstring)."""
    status = setup.status()
    if not status or status["unsolved"]:
        return f"agent not serving: {status and status['unsolved']}"
    wanted = set(status["components"])
    tokens = incarnations(setup)
    if set(tokens) != wanted:
        return f"tokens {sorted(tokens)} but wanted {sorted(wanted)}"
    doubled = {i: t for i, t in tokens.items() if len(t) != 1}
    if doubled:
        return f"instances with several processes: {doubled}"
    pids = {instance: worker_pids(setup, instance) for instance in wanted}
    if any(len(p) != 1 for p in pids.values()):
        return f"status pids per instance: {pids}"
    host = host_status(setup)
    if host is None or host["releasing"] or host["stopping"] or host["pool_starting"]:
        return f"host manager busy: {host and {k: host[k] for k in ('releasing', 'stopping')}}"
    running = worker_processes(setup.domain)
    idle = running - {pid for p in pids.values() for pid in p}
    if len(idle) != host["pool_ready"] or len(idle) > POOL_SIZE:
        return f"worker processes {sorted(running)}, components' {pids}, host {host}"
    return None


def wait_whole(setup: Setup, timeout: float) -> str | None:
    """None once :func:`whole` holds within ``timeout`` seconds, else its last complaint."""
    deadline = time.monotonic() + timeout
    problem = whole(setup)
    while problem is not None and time.monotonic() < deadline:
        time.sleep(0.5)
        problem = whole(setup)
    return problem


def inverted(sample: ErrorPose) -> SimpleNamespace:
    """An HT->WT sample as the WT->HT pose it stands for."""
    rotation, translation = se3.invert(sample.rotation, sample.translation)
    return SimpleNamespace(
        timestamp_ns=sample.timestamp_ns, rotation=rotation, translation=translation
    )


@pytest.fixture
def setup(processes) -> Iterator[Setup]:
    port = free_port()
    domain = f"chaos{port}"
    settings = config.Settings(
        connect=(f"tcp/127.0.0.1:{port}",), listen=("tcp/127.0.0.1:0",), domain=domain
    )
    try:
        with open_session(settings) as session:
            yield Setup(port, domain, KeySpace(settings.key_prefix), session, processes)
    finally:
        kill_tagged(domain)  # workers left by a killed agent, whatever happened


def test_random_faults_leave_one_process_per_component_and_correct_data(setup):
    chaos = Chaos(setup, random.Random(SEED))
    relations = [
        Relation(setup.session, setup.keys, relation, application=f"app{i}")
        for i, relation in enumerate((WT_HT, HT_WT))
    ]
    wait_until(lambda: all(r.latest() is not None for r in relations), timeout=30)

    chaos.run(EVENTS)

    problem = wait_whole(setup, RECOVERY_S)
    assert problem is None, f"not whole {RECOVERY_S} s after the faults {chaos.log}: {problem}"
    for sample in fresh_samples(relations[0], 20):
        assert_true_pose(sample)
    for sample in fresh_samples(relations[1], 20):
        assert_true_pose(inverted(sample))
    assert all(relation.rejected == 0 for relation in relations)
    for relation in relations:
        relation.close()
