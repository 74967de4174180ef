"""The application side's handling of samples (``ubitrack_agent/io/application.py``, issue 11):
a sample stamped far ahead of the clock is rejected and counted, and never freezes
``latest()``; and of the agent's answer (issue 31): one that the relation cannot be served, or
no agent, ends a wait at once unless the relation keeps waiting."""

from __future__ import annotations

import threading
import time
from types import SimpleNamespace

import pytest

from tests.unit.test_worker_inputs import FakeSession, pose
from ubitrack_agent.io import application
from ubitrack_agent.io.application import NoAgent, Relation, UnsolvedRelation
from ubitrack_agent.net.answer import NOT_PLANNED, Answer
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


def test_silence_is_explained_by_the_agents_answer_or_its_absence():
    session = FakeSession()
    with Relation(session, KEYS, RELATION, application="app") as relation:
        with pytest.raises(NoAgent, match="no agent is active on ubitrack/test"):
            relation.wait_for(timeout=0.01)
        active = SimpleNamespace(key_expr=f"{KEYS.agent_active('18ea.1')}", kind="SampleKind.PUT")
        session.callbacks[KEYS.all_active_agents()](active)
        with pytest.raises(TimeoutError) as plain:
            relation.get(timeout=0.01)
        assert type(plain.value) is TimeoutError  # an agent, and no reason given
        session.deliver(KEYS.answer(RELATION), b"{not json")
        assert relation.answer is None and relation.rejected == 1
        unsolved = Answer(str(RELATION), False, KEYS.relation(RELATION), "no provider announces")
        session.deliver(KEYS.answer(RELATION), unsolved.encode().encode())
        with pytest.raises(UnsolvedRelation, match="cannot serve it: no provider") as raised:
            relation.wait_for(timeout=0.01)
        assert raised.value.reason == "no provider announces" and relation.answer == unsolved


def test_the_stream_runs_forward_in_time_and_an_older_sample_serves_lookups():
    """When the agent moves a relation to another flow, the new flow's first output may be
    older than the old flow's last: the application is not handed a pose older than one it
    was handed (nor the same instant twice), but the sample fills the buffer for lookups."""
    session = FakeSession()
    passed_on = []
    with Relation(
        session, KEYS, RELATION, application="app", callback=passed_on.append
    ) as relation:
        now = time.time_ns()
        for t in (now - 30_000_000, now - 10_000_000, now - 20_000_000, now - 10_000_000):
            session.deliver(KEYS.relation(RELATION), pose(t))
        session.deliver(KEYS.relation(RELATION), pose(now))
        assert [s.timestamp_ns for s in passed_on] == [
            now - 30_000_000,
            now - 10_000_000,
            now,
        ]
        assert [relation.get(timeout=0).timestamp_ns for _ in range(3)] == [
            s.timestamp_ns for s in passed_on
        ]
        assert relation.counters["out_of_order"] == 2 and relation.received == 3
        assert relation.lookup(now - 20_000_000).timestamp_ns == now - 20_000_000
        assert relation.latest().timestamp_ns == now


def test_a_static_relation_takes_each_new_value_whatever_its_stamp():
    """A static relation's value is replaced, not streamed (its buffer holds the current one):
    the ordering rule is the dynamic stream's only."""
    session = FakeSession()
    static = RelationId("WT", "A", "6D", static=True)
    with Relation(session, KEYS, static, application="app") as relation:
        now = time.time_ns()
        session.deliver(KEYS.relation(static), pose(now))
        session.deliver(KEYS.relation(static), pose(now))
        assert relation.counters["out_of_order"] == 0 and relation.received == 2


def deliver_later(session: FakeSession, key: str, payload: bytes) -> threading.Thread:
    """``payload`` on ``key`` from another thread, as zenoh delivers it, a moment from now."""
    thread = threading.Timer(0.05, session.deliver, (key, payload))
    thread.start()
    return thread


def agent_token(session: FakeSession, kind: str = "SampleKind.PUT") -> None:
    """The active agent's token appearing (or with ``kind`` DELETE going)."""
    token = SimpleNamespace(key_expr=f"{KEYS.agent_active('18ea.1')}", kind=kind)
    session.callbacks[KEYS.all_active_agents()](token)


UNSOLVED = Answer(str(RELATION), False, KEYS.relation(RELATION), "no provider announces frame(s) A")


def test_an_answer_that_the_relation_cannot_be_served_ends_a_long_wait_at_once():
    """Issue 31: the reason as soon as it arrives, not at the wait's timeout (``timeout`` is
    None on an exception that ended the wait before its timeout)."""
    session = FakeSession()
    with Relation(session, KEYS, RELATION, application="app") as relation:
        agent_token(session)
        delivering = deliver_later(session, KEYS.answer(RELATION), UNSOLVED.encode().encode())
        with pytest.raises(UnsolvedRelation) as raised:
            relation.wait_for(timeout=60.0)
        delivering.join()
        assert raised.value.timeout is None and raised.value.reason == UNSOLVED.reason
        assert str(raised.value) == f"{RELATION}: the agent cannot serve it: {UNSOLVED.reason}"
        with pytest.raises(UnsolvedRelation):  # and every later wait, while the answer holds
            relation.get(timeout=60.0)
        assert isinstance(relation.verdict(), UnsolvedRelation)


def test_not_planned_yet_is_no_reason_to_stop_waiting():
    session = FakeSession()
    with Relation(session, KEYS, RELATION, application="app") as relation:
        agent_token(session)
        pending = Answer(str(RELATION), False, KEYS.relation(RELATION), NOT_PLANNED)
        session.deliver(KEYS.answer(RELATION), pending.encode().encode())
        assert relation.verdict() is None
        with pytest.raises(UnsolvedRelation) as raised:
            relation.wait_for(timeout=0.05)
        assert raised.value.timeout == 0.05  # waited to its timeout, then said what it knew
        assert raised.value.reason == NOT_PLANNED


def test_a_relation_asked_to_keep_waiting_waits_to_its_timeout_and_then_says_why():
    session = FakeSession()
    with Relation(session, KEYS, RELATION, application="app", keep_waiting=True) as relation:
        agent_token(session)
        session.deliver(KEYS.answer(RELATION), UNSOLVED.encode().encode())
        assert relation.verdict() is None
        with pytest.raises(UnsolvedRelation) as raised:
            relation.wait_for(timeout=0.05)
        assert raised.value.timeout == 0.05  # it waited for its timeout
        assert "no sample of C->A:6D within 0.05 s: the agent cannot serve it" in str(raised.value)


def test_no_agent_ends_a_long_wait_after_the_grace(monkeypatch):
    """With no active agent's token for ``NO_AGENT_AFTER_S`` (here shortened), a wait ends with
    ``NoAgent`` whatever its timeout; as it does when the agent goes away."""
    monkeypatch.setattr(application, "NO_AGENT_AFTER_S", 0.05)
    session = FakeSession()
    with Relation(session, KEYS, RELATION, application="app") as relation:
        with pytest.raises(NoAgent) as raised:
            relation.wait_for(timeout=60.0)
        assert raised.value.timeout is None
        agent_token(session)
        assert relation.verdict() is None
        agent_token(session, "SampleKind.DELETE")  # it went away
        with pytest.raises(NoAgent) as raised:
            relation.get(timeout=60.0)
        assert raised.value.timeout is None
    with Relation(session, KEYS, RELATION, application="app", keep_waiting=True) as relation:
        with pytest.raises(NoAgent) as raised:
            relation.wait_for(timeout=0.1)
        assert raised.value.timeout == 0.1  # kept waiting, to its timeout


def test_once_samples_have_come_waits_run_to_their_timeout():
    """A sample already there is handed over whatever the answer; after the first sample the
    answer no longer ends a wait early (an agent restarting, a flow replanned)."""
    session = FakeSession()
    with Relation(session, KEYS, RELATION, application="app") as relation:
        now = time.time_ns()
        session.deliver(KEYS.relation(RELATION), pose(now))
        session.deliver(KEYS.answer(RELATION), UNSOLVED.encode().encode())
        assert relation.get(timeout=60.0).timestamp_ns == now
        assert relation.verdict() is None
        with pytest.raises(UnsolvedRelation) as raised:
            relation.get(timeout=0.05)
        assert raised.value.timeout == 0.05
