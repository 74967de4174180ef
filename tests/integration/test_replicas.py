"""Replicas (``ubitrack agent --replicas``, ``agent.spares``): the relation's derivation runs
twice, in two containers, both producers on the relation's key; when the process running the
one that holds the key dies, the other, its filters warm, takes the key at its next sample
(hand-over rule 5), with no duplicate and no instant out of order, and the container restored
by its host manager serves as the replica from then on."""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest

from tests.integration.test_agent import WT_HT, assert_true_pose, fresh_samples, setup  # noqa: F401
from tests.integration.test_data_liveness import alive_spare, worker_status
from tests.integration.zenoh_helpers import Collector, wait_until
from ubitrack_agent.core.codec import decode
from ubitrack_agent.io.application import Relation

pytestmark = pytest.mark.integration


def producers(status: dict | None, relation: str) -> tuple[str | None, str | None]:
    """The relation's producer and its first replica, once both are alive."""
    replica = alive_spare(status, relation)
    components = (status or {}).get("components", {})
    primary = next(
        (
            instance
            for instance, component in components.items()
            if component["relations"] and component["alive"] and instance != replica
        ),
        None,
    )
    return (primary, replica) if primary and replica else (None, None)


def holder_first(setup, pair: tuple[str, str], key: str) -> tuple[str, str] | None:  # noqa: F811
    """``pair`` with the one holding ``key`` first, once exactly one does."""
    holding = [instance for instance in pair if worker_status(setup, instance)["holds"] == [key]]
    if len(holding) != 1:
        return None
    return (holding[0], next(i for i in pair if i != holding[0]))


def test_a_replica_takes_the_relation_at_once_when_its_twins_container_dies(setup):  # noqa: F811
    setup.start_agent("--replicas", "1")
    setup.tracker("art", "ART", 30.0, 2.0)
    relation = Relation(setup.session, setup.keys, WT_HT, application="app")
    key = setup.keys.relation(WT_HT)
    collector = Collector(setup.session, key)
    try:
        pair = wait_until(lambda: all(p := producers(setup.status(), "WT->HT:6D")) and p, 30)
        components = setup.status()["components"]
        assert components[pair[0]]["container"] != components[pair[1]]["container"]
        assert components[pair[0]]["service"] == components[pair[1]]["service"]
        holder, twin = wait_until(lambda: holder_first(setup, pair, key), timeout=10)
        incarnation = worker_status(setup, twin)["incarnation"]
        fresh_samples(relation, 5)

        os.kill(components[holder]["pid"], signal.SIGKILL)  # the holder's whole container
        killed = time.time_ns()
        for sample in fresh_samples(relation, 20):
            assert_true_pose(sample)
        status = worker_status(setup, twin)
        assert status["incarnation"] == incarnation  # it ran on, its state warm
        # the key free at once (rule 5): the twin put its next sample
        counters = {k: v for k, v in status["counters"].items() if k.startswith("relation_") and v}
        assert counters.get("relation_holder_left") == 1, counters
        wait_until(lambda: holder in setup.alive_services(), timeout=30)  # restored
        wait_until(lambda: holder_first(setup, pair, key), timeout=10)  # one of the two holds
        for sample in fresh_samples(relation, 20):
            assert_true_pose(sample)

        stamps = []
        while not collector.items.empty():
            stamps.append(decode(collector.items.get_nowait()).timestamp_ns)
        assert len(stamps) > 45 and np.all(np.diff(stamps) > 0)  # no duplicate, in order
        before = max(s for s in stamps if s <= killed)
        after = min(s for s in stamps if s > killed)
        print(f"interval across the kill: {(after - before) / 1e6:.1f} ms")
    finally:
        collector.subscriber.undeclare()
        relation.close()
