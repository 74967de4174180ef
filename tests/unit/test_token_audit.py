"""Tokens the agent's subscriptions missed, found by asking (``agent/token_audit.py`` and the
agent's ``_audit_tokens`` and ``_handle`` of ``FOUND`` events), without a session: a token two
questions in a row found undelivered is taken as appeared and counted, a delivered one (or one
delivered between the questions) changes nothing, one removed since the question is not
brought back, and a hostile key among the replies is refused once."""

from __future__ import annotations

import queue
from types import SimpleNamespace

from tests.unit.test_agent_workers import KEYS
from tests.unit.test_agent_workers import agent as workers_agent
from ubitrack_agent.agent import token_audit
from ubitrack_agent.agent.problems import Problems
from ubitrack_agent.agent.runtime import PUT, Agent
from ubitrack_agent.agent.token_audit import AUDIT_S, TokenAudit

DELETE = "SampleKind.DELETE"


def test_a_token_two_questions_found_undelivered_is_missed_and_a_delivered_one_is_not():
    audit = TokenAudit()
    audit.delivered("worker", "w/1", appeared=True)
    audit.asked(1.0)
    assert not audit.missed("worker", "w/1")
    assert not audit.missed("worker", "w/2")  # perhaps declared just before the question
    assert not audit.missed("worker", "w/3")
    audit.delivered("worker", "w/3", appeared=True)  # its appearance came after all
    audit.asked(1.0 + AUDIT_S)
    assert audit.missed("worker", "w/2")
    assert not audit.missed("worker", "w/3")
    assert not audit.missed("provider", "w/1")  # per kind: first found now


def test_a_token_removed_after_the_question_is_not_brought_back_by_its_reply():
    audit = TokenAudit()
    audit.delivered("worker", "w/2", appeared=True)
    audit.delivered("worker", "w/2", appeared=False)
    audit.asked(1.0)
    assert not audit.missed("worker", "w/1")  # its appearance missed
    assert not audit.missed("worker", "w/2")  # up again, its appearance missed
    audit.asked(2.0)
    audit.delivered("worker", "w/1", appeared=False)  # removed after this question
    assert not audit.missed("worker", "w/1")  # the reply predates its removal
    assert audit.missed("worker", "w/2")


def test_the_question_is_due_every_audit_s_and_old_findings_are_forgotten():
    audit = TokenAudit()
    assert audit.due(0.0)
    audit.asked(0.0)
    assert not audit.due(AUDIT_S - 0.1) and audit.due(AUDIT_S)
    assert not audit.missed("worker", "w/2")
    audit.asked(AUDIT_S)
    assert ("worker", "w/2") in audit._undelivered
    audit.asked(2 * AUDIT_S)  # not found by the question of AUDIT_S: forgotten
    assert audit._undelivered == {}
    audit.asked(3 * AUDIT_S)
    assert not audit.missed("worker", "w/2")  # a first finding again


class FakeLiveliness:
    """``session.liveliness()``: ``get`` answers at once with the replies given."""

    def __init__(self, replies: dict[str, list[str | None]]) -> None:
        self.replies = replies
        self.asked: list[str] = []

    def get(self, selector, handler, timeout=None):
        self.asked.append(selector)
        for key in self.replies.get(selector, []):
            ok = None if key is None else SimpleNamespace(key_expr=key)
            handler(SimpleNamespace(ok=ok))


def agent(replies: dict[str, list[str | None]]) -> tuple[Agent, FakeLiveliness]:
    """An agent's token handling alone (its worker bookkeeping, ``test_agent_workers``),
    settled, on a fake session."""
    bare, _ = workers_agent()
    bare.problems = Problems(bare.counters)
    bare._events = queue.SimpleQueue()
    bare._audit = TokenAudit()
    bare._started = -1e9
    bare._watched = (("worker", KEYS.all_workers()), ("provider", KEYS.all_providers()))
    liveliness = FakeLiveliness(replies)
    bare.session = SimpleNamespace(liveliness=lambda: liveliness)
    return bare, liveliness


def handle_queued(bare: Agent) -> list[bool]:
    changed = []
    while not bare._events.empty():
        changed.append(bare._handle(*bare._events.get_nowait()))
    return changed


def test_a_worker_the_subscription_missed_is_taken_as_alive_when_found_twice(monkeypatch):
    seen, missed = KEYS.worker("seen-1", "10.aaaa"), KEYS.worker("missed-1", "11.bbbb")
    bare, liveliness = agent({KEYS.all_workers(): [seen, missed, None]})
    bare._handle("worker", PUT, seen)  # delivered by the subscription
    bare._audit_tokens()
    assert liveliness.asked == [KEYS.all_workers(), KEYS.all_providers()]
    assert handle_queued(bare) == [False, False]
    bare._audit_tokens()  # within AUDIT_S: not asked again
    assert len(liveliness.asked) == 2 and bare.alive == {"seen-1"}
    monkeypatch.setattr(token_audit, "AUDIT_S", 0.0)
    bare._audit_tokens()
    assert handle_queued(bare) == [False, True]  # the missed one is new: may be planned with
    assert bare.alive == {"seen-1", "missed-1"}
    assert bare.counters["tokens_found"] == 1


def test_a_worker_removed_after_the_question_is_not_brought_back_by_its_reply(monkeypatch):
    monkeypatch.setattr(token_audit, "AUDIT_S", 0.0)
    key = KEYS.worker("gone-1", "12.cccc")
    bare, _ = agent({KEYS.all_workers(): [key]})
    bare._audit_tokens()
    handle_queued(bare)  # found undelivered once
    bare._handle("worker", PUT, key)
    bare._audit_tokens()  # its reply is queued ...
    reply = bare._events.get_nowait()
    bare._handle("worker", DELETE, key)  # ... and the removal is handled first
    assert bare._handle(*reply) is False
    assert "gone-1" not in bare.alive and bare.counters["tokens_found"] == 0


def test_a_found_provider_is_fetched_and_a_hostile_key_refused_once(monkeypatch):
    monkeypatch.setattr(token_audit, "AUDIT_S", 0.0)
    provider = KEYS.provider("ART")
    hostile = "ubitrack/test/provider/" + "x" * 5000
    bare, _ = agent({KEYS.all_providers(): [provider, hostile]})
    bare._pending_fragments = {}
    bare.liveness = SimpleNamespace(forget=lambda provider: None)
    for _ in range(3):
        bare._audit_tokens()
        handle_queued(bare)
    assert "ART" in bare._pending_fragments  # its fragment is fetched, as for a token seen
    assert bare.counters["tokens_found"] == 1
    assert bare.counters["rejected_provider_keys"] == 1


def test_a_malformed_key_delivered_and_found_again_is_refused_once(monkeypatch):
    monkeypatch.setattr(token_audit, "AUDIT_S", 0.0)
    hostile = "ubitrack/test/worker/no-incarnation"  # one chunk where two belong
    bare, _ = agent({KEYS.all_workers(): [hostile]})
    bare._audit_tokens()
    handle_queued(bare)  # found before its appearance is delivered
    bare._handle("worker", PUT, hostile)
    for _ in range(2):
        bare._audit_tokens()
        handle_queued(bare)
    assert bare.counters["rejected_worker_keys"] == 1 and bare.counters["tokens_found"] == 0
