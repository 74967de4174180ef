"""Chaos without orphans (issue 11, item 3): a seeded run of random faults against a live
agent, its host manager, two noise-free trackers and applications listening, then checks
that the system is whole again within ``RECOVERY_S``.

Faults (``chaos_faults.Chaos``, shared with the churn and recovery benchmarks), drawn from
``random.Random(SEED)`` (``UBITRACK_CHAOS_SEED`` overrides it):

* a tracker killed (SIGKILL or SIGTERM) and started again;
* a worker killed (SIGKILL or SIGTERM; the agent starts it again);
* the agent killed (SIGKILL: its workers keep running and the restarted agent adopts them;
  or SIGTERM: a clean stop, which leaves them running too) and started again;
* a flapping application: a query opened and closed again within 0.05-0.4 s, so workers are
  told to stop while they are starting.

Every sample the applications receive, during the faults and after, is judged against the
trackers' truth (issue 29, ``chaos_faults.judged``): none may be beyond 5 cm, 5 degrees or 3
sigma of its own covariance. After the faults every process is back and the checks must hold
within ``RECOVERY_S``: every application receives fresh samples equal to the trackers' known
truth, each wanted component
runs in exactly one process (one token incarnation, one status pid), no worker runs that
nothing wants, and every worker process of the domain (``ps``) is either a wanted
component's or an idle member the host manager counts in its pool: none leaked. Every
process is killed at the end, pass or fail (the ``processes`` fixture and ``kill_tagged``).
"""

from __future__ import annotations

import os
import random
from collections.abc import Iterator
from types import SimpleNamespace

import pytest

from tests.integration.chaos_faults import (
    HT_WT,
    WT_HT,
    Chaos,
    Judged,
    judged,
    tagged_setup,
    wait_whole,
)
from tests.integration.test_agent import Setup, assert_true_pose, fresh_samples
from tests.integration.zenoh_helpers import wait_until
from ubitrack_agent.core import ErrorPose, se3
from ubitrack_agent.io.application import Relation
from ubitrack_agent.net.keys import RelationId

pytestmark = pytest.mark.integration

SEED = int(os.environ.get("UBITRACK_CHAOS_SEED", "11"))
EVENTS = 14
"""Faults per run, one every 1.0-2.5 s: each kind three times, two more at random."""
RECOVERY_S = 40.0
"""After the last fault, the time within which every check must hold (typically 5-15 s: up
to ten workers may have to start cold on a loaded machine)."""


def inverted(sample: ErrorPose) -> SimpleNamespace:
    """An HT->WT sample as the WT->HT pose it stands for."""
    rotation, translation = se3.invert(sample.rotation, sample.translation)
    return SimpleNamespace(
        timestamp_ns=sample.timestamp_ns, rotation=rotation, translation=translation
    )


@pytest.fixture
def setup(processes) -> Iterator[Setup]:
    yield from tagged_setup(processes, "chaos")


def test_random_faults_leave_one_process_per_component_and_correct_data(setup):
    chaos = Chaos(setup, random.Random(SEED))
    received: list[tuple[RelationId, int, Judged]] = []

    def judge(relation: RelationId):
        return lambda sample: received.append(
            (relation, sample.timestamp_ns, judged(relation, sample))
        )

    relations = [
        Relation(
            setup.session, setup.keys, relation, application=f"app{i}", callback=judge(relation)
        )
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
    wrong = [(str(r), stamp, j) for r, stamp, j in list(received) if j.wrong]
    assert len(received) > 1000, f"only {len(received)} samples received in the whole run"
    assert not wrong, f"{len(wrong)} of {len(received)} samples wrong, the first: {wrong[:5]}"
    for relation in relations:
        relation.close()
