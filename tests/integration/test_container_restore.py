"""A container with ten or more components killed (issue 28, failure containment; issue 29,
the gap after it): every application it fed receives correct samples again, and afterwards
nothing unwanted runs.

The system is the chaos test's (``chaos_faults.Chaos``: an agent, two noise-free trackers),
with the host manager started on its own with ``--cores 1`` so that every component of the
four applications (``WT->HT``, ``HT->WT``, ``HT->ART``, ``HT->IR``) runs in one container. The
container is SIGKILLed; its host manager restores it, from its warm pool or, with none, in a
process it starts. Checked, each with a bounded wait that fails saying what is missing (how
long it takes is measured by ``bench.recovery_bench``, not here): each application receives a
sample stamped after the kill and true to the trackers' known truth; every component runs
again, all of them in one new process; and the system is whole (``chaos_faults.whole``: one
process per wanted component, none unwanted, every other worker process a pool member). Every
process is killed at the end, pass or fail.
"""

from __future__ import annotations

import os
import random
import signal
import threading
import time
from collections.abc import Iterator

import pytest

from tests.integration.chaos_faults import (
    HT_WT,
    TRUE_WITHIN_M,
    WT_HT,
    Chaos,
    host_status,
    tagged_setup,
    truth_error,
    wait_whole,
)
from tests.integration.test_agent import Setup
from tests.integration.zenoh_helpers import wait_until
from ubitrack_agent.io.application import Relation
from ubitrack_agent.net.keys import RelationId

pytestmark = pytest.mark.integration

RELATIONS = (WT_HT, HT_WT, RelationId("HT", "ART", "6D"), RelationId("HT", "IR", "6D"))
SETTLE_S = 90.0
"""Bound of the waits for the system to start and to be whole again (a cold container's
imports on a loaded machine take seconds)."""


@pytest.fixture
def setup(processes) -> Iterator[Setup]:
    yield from tagged_setup(processes, "restore")


class Received:
    """Each application's samples as they arrive: stamp (ns) and error against the truth."""

    def __init__(self, setup: Setup) -> None:
        self._lock = threading.Lock()
        self.samples: dict[RelationId, list[tuple[int, float]]] = {r: [] for r in RELATIONS}
        self.relations = [
            Relation(setup.session, setup.keys, r, application=f"app{i}", callback=self._note(r))
            for i, r in enumerate(RELATIONS)
        ]

    def _note(self, relation: RelationId):
        def note(sample) -> None:
            with self._lock:
                self.samples[relation].append((sample.timestamp_ns, truth_error(relation, sample)))

        return note

    def missing(self, after_ns: int) -> list[str]:
        """The applications without a true sample stamped after ``after_ns``."""
        with self._lock:
            return [
                str(r)
                for r, noted in self.samples.items()
                if not any(t > after_ns and error <= TRUE_WITHIN_M for t, error in noted)
            ]

    def close(self) -> None:
        for relation in self.relations:
            relation.close()


@pytest.mark.parametrize("pool_size", [2, 0], ids=["warm pool", "no pool"])
def test_a_killed_container_of_ten_components_feeds_every_application_again(setup, pool_size):
    chaos = Chaos(setup, random.Random(0), pool_size=pool_size, cores=1)
    received = Received(setup)
    try:
        start = time.time_ns()
        wait_until(lambda: not received.missing(start), timeout=SETTLE_S)
        problem = wait_whole(setup, SETTLE_S, pool_size)
        assert problem is None, f"never whole before the kill: {problem}"
        before = host_status(setup)
        assert before is not None, "the host manager does not answer"
        pids = {entry["pid"] for entry in before["instances"].values()}
        assert len(pids) == 1, f"components in several processes: {before['instances']}"
        assert len(before["instances"]) >= 10, f"fewer than ten: {sorted(before['instances'])}"

        killed, killed_ns = pids.pop(), time.time_ns()
        os.kill(killed, signal.SIGKILL)

        deadline = time.monotonic() + SETTLE_S
        while (missing := received.missing(killed_ns)) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not missing, f"no true sample after the kill within {SETTLE_S} s: {missing}"
        problem = wait_whole(setup, SETTLE_S, pool_size)
        assert problem is None, f"not whole {SETTLE_S} s after the kill: {problem}"
        after = host_status(setup)
        assert after is not None, "the host manager does not answer"
        assert set(after["instances"]) == set(before["instances"])  # the same components
        new_pids = {entry["pid"] for entry in after["instances"].values()}
        assert len(new_pids) == 1 and killed not in new_pids, (killed, new_pids)
        assert after["counters"].get("containers_restored", 0) == 1
        assert chaos.host is not None and chaos.host.poll() is None
    finally:
        received.close()
