"""The live agent with real zenoh on loopback and real processes: sensors come and go,
applications share flows, workers are killed, the agent itself is killed and restarted."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import pytest

from tests.integration.conftest import kill_tagged
from tests.integration.zenoh_helpers import free_port, member_flags, wait_until
from ubitrack_agent.core import se3
from ubitrack_agent.io.application import Relation
from ubitrack_agent.net import config
from ubitrack_agent.net.host_protocol import Status, encode_request
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.session import open_session
from ubitrack_agent.net.transport import fetch_latest
from ubitrack_agent.sim_trackers.exact_tracker import true_wt_ht

pytestmark = pytest.mark.integration

WT_HT = RelationId("WT", "HT", "6D")


@dataclass
class Setup:
    port: int
    domain: str
    keys: KeySpace
    session: object
    processes: list

    def start(self, *command: str) -> subprocess.Popen:
        process = subprocess.Popen(
            [sys.executable, *command, *member_flags(self.port, self.domain)],
            start_new_session=True,
        )
        self.processes.append(process)
        return process

    def start_agent(self, *extra: str, wait: bool = True) -> subprocess.Popen:
        """The agent (``extra``: more of its options), waiting until it answers if ``wait``."""
        process = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "ubitrack_agent.cli",
                "--log-level",
                "INFO",
                "agent",
                "--listen",
                f"tcp/127.0.0.1:{self.port}",
                "--domain",
                self.domain,
                *extra,
            ],
            start_new_session=True,
        )
        self.processes.append(process)
        if wait:
            wait_until(lambda: self.status() is not None, timeout=20)
        return process

    def tracker(self, provider: str, tracker: str, yaw: float, x: float) -> subprocess.Popen:
        return self.start(
            "-m",
            "ubitrack_agent.sim_trackers.exact_tracker",
            "--provider",
            provider,
            "--tracker",
            tracker,
            "--yaw",
            str(yaw),
            "--x",
            str(x),
        )

    def status(self) -> dict | None:
        replies = fetch_latest(self.session, self.keys.agent_status(), timeout=0.5)
        return json.loads(replies[0]) if replies else None

    def alive_services(self) -> dict[str, str]:
        """Alive components by id: their service names."""
        status = self.status() or {"components": {}}
        return {i: c["service"] for i, c in status["components"].items() if c["alive"]}

    def worker_pid(self, instance: str) -> int | None:
        replies = fetch_latest(self.session, self.keys.status(instance), timeout=0.5)
        return json.loads(replies[0])["pid"] if replies else None


@pytest.fixture
def setup(processes) -> Iterator[Setup]:
    yield from opened(processes)


def opened(processes: list) -> Iterator[Setup]:
    """A setup on a fresh port and domain, its session open until the generator ends; then the
    processes tagged with its domain are killed (``processes`` are the caller's to end)."""
    port = free_port()
    domain = f"agent{port}"
    settings = config.Settings(
        connect=(f"tcp/127.0.0.1:{port}",), listen=("tcp/127.0.0.1:0",), domain=domain
    )
    with open_session(settings) as session:
        yield Setup(port, domain, KeySpace(settings.key_prefix), session, processes)
    kill_tagged(domain)  # workers the test orphaned on purpose by killing the agent


def assert_true_pose(sample) -> None:
    """Trackers publish exact poses, but fusing two unsynchronised trackers evaluates one of
    them at the other's instants: interpolated (errors far below 1 mm), or, when its next
    sample is late, its nearest sample within the 5 ms tolerance (up to 2.2 mm on this path,
    ``ubitrack_agent.sim_trackers.exact_tracker.PATH``). Hence 3 mm."""
    q, t = true_wt_ht(sample.timestamp_ns)
    np.testing.assert_allclose(
        se3.to_matrix(sample.rotation, sample.translation), se3.to_matrix(q, t), atol=3e-3
    )


def fresh_samples(relation: Relation, count: int, timeout: float = 10.0) -> list:
    """``count`` samples produced after this call (older ones are flushed first)."""
    start = time.time_ns()
    samples = []
    deadline = time.monotonic() + timeout
    while len(samples) < count:
        sample = relation.get(timeout=max(0.01, deadline - time.monotonic()))
        if sample.timestamp_ns > start:
            samples.append(sample)
    return samples


def test_sensors_appear_vanish_and_return_while_the_application_keeps_its_key(setup):
    setup.start_agent()
    relation = Relation(setup.session, setup.keys, WT_HT, application="app1")
    with pytest.raises(TimeoutError):
        relation.wait_for(timeout=0.3)  # no sensor yet, nothing to plan
    art = setup.tracker("art", "ART", 30.0, 2.0)
    setup.tracker("ir", "IR", 100.0, -1.0)
    wait_until(lambda: "fusion" in setup.alive_services().values(), timeout=20)
    for sample in fresh_samples(relation, 20):
        assert_true_pose(sample)

    art.send_signal(signal.SIGTERM)  # one tracker leaves: the flow falls back to the other
    wait_until(lambda: "fusion" not in setup.alive_services().values(), timeout=10)
    for sample in fresh_samples(relation, 20):
        assert_true_pose(sample)
    status = setup.status()
    assert not any("art/" in b["key"] for c in status["components"].values() for b in c["inputs"])

    setup.tracker("art", "ART", 30.0, 2.0)  # it comes back: fusion again
    wait_until(lambda: "fusion" in setup.alive_services().values(), timeout=20)
    for sample in fresh_samples(relation, 20):
        assert_true_pose(sample)
    assert relation.rejected == 0
    relation.close()
    wait_until(lambda: not setup.alive_services(), timeout=10)  # nobody asks: all stopped


def test_applications_share_flows_and_workers_are_restarted(setup):
    setup.start_agent()
    setup.tracker("art", "ART", 30.0, 2.0)
    first = Relation(setup.session, setup.keys, WT_HT, application="first")
    wait_until(lambda: first.latest() is not None, timeout=20)
    alone = dict(setup.alive_services())
    same = Relation(setup.session, setup.keys, WT_HT, application="second")
    inverse = Relation(setup.session, setup.keys, RelationId("HT", "WT", "6D"), application="third")
    wait_until(lambda: inverse.latest() is not None, timeout=20)
    shared = setup.alive_services()
    assert set(alone) <= set(shared)  # the first flow keeps running, shared
    assert len(shared) < 2 * len(alone) + 1  # the inverse reuses it rather than duplicating
    assert setup.status()["queries"][str(WT_HT)] == ["first", "second"]
    fresh_samples(same, 5)

    victim = next(i for i, s in shared.items() if s == "concatenation")
    pid = setup.worker_pid(victim)
    os.kill(pid, signal.SIGKILL)
    wait_until(lambda: (p := setup.worker_pid(victim)) is not None and p != pid, timeout=20)
    for sample in fresh_samples(first, 10):
        assert_true_pose(sample)
    # its container was restored by the host manager, and its components sent their wiring
    assert setup.status()["counters"]["restored"] >= 1

    first.close()  # "second" still asks for the same relation: the flow stays
    time.sleep(0.3)
    assert set(alone) <= set(setup.alive_services())
    fresh_samples(same, 5)
    for relation in (same, inverse):
        relation.close()
    wait_until(lambda: not setup.alive_services(), timeout=10)


def test_a_killed_agent_is_restarted_and_rebuilds_everything(setup):
    agent = setup.start_agent()
    setup.tracker("art", "ART", 30.0, 2.0)
    relation = Relation(setup.session, setup.keys, WT_HT, application="app")
    wait_until(lambda: relation.latest() is not None, timeout=20)
    before = setup.alive_services()
    pids = {instance: setup.worker_pid(instance) for instance in before}
    placed = {i: (c["host"], c["container"]) for i, c in setup.status()["components"].items()}
    host_pid = host_manager_pid(setup, placed)

    os.kill(agent.pid, signal.SIGKILL)  # the agent dies; its host manager and workers keep
    agent.wait()  # the data flowing (the workers are the host manager's clients)
    fresh_samples(relation, 10)

    setup.start_agent()  # rebuilt from liveliness alone: adopts the running workers
    counters = wait_until(  # generous: under load a new agent is slow to import and settle
        lambda: (
            (c := (setup.status() or {}).get("counters", {})).get("adopted", 0) >= len(before) and c
        ),
        timeout=40,
    )
    assert counters["adopted"] == len(before), counters  # each once: no step down and up again
    wait_until(lambda: components_placed(setup) == placed, timeout=10)
    status = setup.status()
    assert {i: c["service"] for i, c in status["components"].items()} == before
    assert host_manager_pid(setup, placed) == host_pid  # adopted too, not started again
    assert {instance: setup.worker_pid(instance) for instance in before} == pids  # not restarted
    for sample in fresh_samples(relation, 10):
        assert_true_pose(sample)
    relation.close()
    wait_until(lambda: not setup.alive_services(), timeout=10)


def components_placed(setup: Setup) -> dict[str, tuple[str | None, str | None]]:
    """Each component's host and container, as the agent records them."""
    status = setup.status() or {"components": {}}
    return {i: (c["host"], c["container"]) for i, c in status["components"].items()}


def host_manager_pid(setup: Setup, placed: dict[str, tuple[str | None, str | None]]) -> int:
    """The pid of the one host manager the components are placed on."""
    (host,) = {host for host, _ in placed.values()}
    replies = setup.session.get(
        setup.keys.host_request(host), payload=encode_request(Status()), timeout=2.0
    )
    return json.loads(next(r.ok for r in replies if r.ok is not None).payload.to_bytes())["pid"]


def test_malformed_announcements_and_queries_are_rejected_and_counted(setup):
    import threading

    setup.start_agent()
    # A provider whose fragment is garbage, and one whose fragment names frames with wildcards.
    bad = {
        "junk": b"{not json",
        "hostile": json.dumps(
            {
                "provider": "hostile",
                "edges": [{"name": "x", "from": "**", "to": "HT", "type": "6D"}],
            }
        ).encode(),
    }
    queryables = []
    for provider, payload in bad.items():
        queryable = setup.session.declare_queryable(setup.keys.fragment(provider))

        def serve(queryable=queryable, payload=payload):
            for query in queryable:
                with query:
                    query.reply(query.key_expr, payload)

        threading.Thread(target=serve, daemon=True).start()
        queryables.append(queryable)
    silent = ["silent"]  # a token and no fragment: asked a few times, then rejected
    tokens = [
        setup.session.liveliness().declare_token(setup.keys.provider(p)) for p in [*bad, *silent]
    ]
    tokens.append(setup.session.liveliness().declare_token(f"{setup.keys.root}/query/a/b"))
    setup.tracker("art", "ART", 30.0, 2.0)
    relation = Relation(setup.session, setup.keys, WT_HT, application="good")
    wait_until(lambda: relation.latest() is not None, timeout=20)  # still serving the others
    status = wait_until(
        lambda: (s := setup.status()) and len(s["rejected_providers"]) == 3 and s, timeout=20
    )
    assert "not JSON" in status["rejected_providers"]["junk"]
    assert "from" in status["rejected_providers"]["hostile"]
    assert "no fragment" in status["rejected_providers"]["silent"]
    assert status["counters"]["rejected_announcements"] == 3
    assert status["counters"]["rejected_query_keys"] == 1
    assert set(status["providers"]) == {"art"}
    for token in tokens:
        token.undeclare()
    for queryable in queryables:
        queryable.undeclare()
    relation.close()
