"""The application side's handling of samples (``ubitrack_agent/io/application.py``, issue 11):
a sample stamped far ahead of the clock is rejected and counted, and never freezes
``latest()``."""

from __future__ import annotations

import time

from tests.unit.test_worker_inputs import FakeSession, pose
from ubitrack_agent.io.application import Relation
from ubitrack_agent.net.keys import KeySpace, RelationId

KEYS = KeySpace("ubitrack/test")
RELATION = RelationId("C", "A", "6D")


def test_a_future_sample_never_becomes_latest():
    """Regression: ``latest()`` kept returning a pose stamped a day ahead."""
    session = FakeSession()
    with Relation(session, KEYS, RELATION, application="app") as relation:
        now = time.time_ns()
        session.deliver(KEYS.relation(RELATION), pose(now + 86_400 * 10**9))
        assert relation.counters["rejected_future"] == 1 and relation.latest() is None
        session.deliver(KEYS.relation(RELATION), pose(now))
        session.deliver(KEYS.relation(RELATION), pose(now + 1_000))
        assert relation.latest().timestamp_ns == now + 1_000
        assert relation.received == 2 and relation.rejected == 0


def test_a_broken_callback_or_garbage_never_raises_into_zenoh():
    session = FakeSession()

    def broken(sample):
        raise RuntimeError("application bug")

    with Relation(session, KEYS, RELATION, application="app", callback=broken) as relation:
        session.deliver(KEYS.relation(RELATION), b"garbage")
        session.deliver(KEYS.relation(RELATION), pose(time.time_ns()))
        assert relation.rejected == 1 and relation.received == 1
