"""Tokens the agent's liveliness subscriptions did not deliver, found by asking for them.

The agent learns of providers, queries, workers and other agents from liveliness subscriptions
with history (:mod:`.runtime`). Such a subscription has been seen to miss a token: in one CI
run a host manager never saw the token of a container that served all along (issue 28;
``services/supervisor.py``, ``TOKEN_ASK_S``). A missed appearance is lost for good: a provider
never seen is never planned with, a worker never seen is never adopted (and is started
again). So every :data:`AUDIT_S` the agent asks for every live token of each kind (a liveliness
query, non-blocking; the replies come back to its loop as ``FOUND`` events), and a token found
that its subscription has not delivered is taken as appeared, and counted (``tokens_found``).

Only appearances: a missed removal is noticed by other paths (a host manager reports a
worker's exit; a provider's data goes quiet and its edges stale, :mod:`.liveness`; an
application's relation is then merely served longer), where taking a token as gone because
one query did not list it would stop or restart what still runs.

Races (:meth:`TokenAudit.missed`): a token declared just before a question may be in its reply
before the subscription delivers it, so a token is taken as missed only when two questions in a
row found it undelivered (the subscription delivers within milliseconds, a question comes every
:data:`AUDIT_S`): a missed token is applied 5-10 s after its appearance. A reply may also come
after the token's removal, which came after the question: the removal, delivered, clears what
the questions found, so the reply counts as a first finding again. Replies come within
:data:`AUDIT_TIMEOUT_S`, before the next question.

Cost: per :data:`AUDIT_S`, one query per kind and ``O(live tokens)`` replies, each an ``O(1)``
look-up; memory ``O(live tokens + undelivered tokens found by the last two questions)``.
"""

from __future__ import annotations

from collections import defaultdict

AUDIT_S = 5.0
"""How often the agent asks for every live token (after start-up has settled)."""
AUDIT_TIMEOUT_S = 2.0
"""How long one question's replies may take (less than :data:`AUDIT_S`)."""
FOUND = "FOUND"
"""The change of an event made from a reply to the question (beside zenoh's PUT and DELETE)."""


class TokenAudit:
    """The tokens the agent's subscriptions delivered, per kind, and when to ask again."""

    def __init__(self) -> None:
        self._live: dict[str, set[str]] = defaultdict(set)
        self._undelivered: dict[tuple[str, str], float] = {}
        """Tokens a question found that the subscription had not delivered, with the
        question's time, kept for two questions."""
        self._asked_at = -float("inf")
        self._asked_before = -float("inf")

    def delivered(self, kind: str, key: str, appeared: bool) -> None:
        """A token event the agent applied (from its subscription, or a missed one)."""
        self._undelivered.pop((kind, key), None)
        if appeared:
            self._live[kind].add(key)
        else:
            self._live[kind].discard(key)

    def due(self, now: float) -> bool:
        """Whether to ask again (every :data:`AUDIT_S`)."""
        return now - self._asked_at >= AUDIT_S

    def asked(self, now: float) -> None:
        """The question went out at ``now``: forget what is older than the previous one."""
        self._asked_before, self._asked_at = self._asked_at, now
        self._undelivered = {
            token: at for token, at in self._undelivered.items() if at >= self._asked_before
        }

    def missed(self, kind: str, key: str) -> bool:
        """Whether a token the last question found is one the subscription missed: not
        delivered, and found undelivered by the question before too, with no event of it
        delivered since (module docstring)."""
        if key in self._live[kind]:
            return False
        if self._undelivered.get((kind, key)) == self._asked_before:
            return True
        self._undelivered.setdefault((kind, key), self._asked_at)
        return False
