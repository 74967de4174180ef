"""What an application waiting for a relation's first sample can say meanwhile (issue 31, item 1).

:class:`Relation <ubitrack_agent.io.application.Relation>` ends a wait at once when the agent
answers that it cannot serve the relation, or when no agent is there; this module says the
rest, for ``ubitrack subscribe`` and ``ubitrack calibrate`` and for any application:

* :class:`StartWatch`: how far the flow the agent planned for the relation has started,
  ``planned: 3 components, 1 alive``: the answer names the flow's components (``net.answer``),
  and each running component holds a worker token (``<root>/worker/<instance>/<incarnation>``,
  ``net.keys``), which the watch follows as the agent does (an instance is alive while it has
  a token);
* :func:`network_of`: where a command looked for the agent, ``tcp/127.0.0.1:7448/default``, for
  its "no agent" message.
"""

from __future__ import annotations

import logging
import threading
from collections import Counter
from collections.abc import Callable, Collection
from typing import Any

from ubitrack_agent.net import logs
from ubitrack_agent.net.answer import Answer, AnswerError, parse_answer
from ubitrack_agent.net.config import Settings
from ubitrack_agent.net.keys import KeyRejection, KeySpace, RelationId
from ubitrack_agent.net.lifecycle import Closing
from ubitrack_agent.net.transport import fetch_until_satisfied

log = logging.getLogger("ubitrack.waiting")


def network_of(settings: Settings) -> str:
    """Where a process looks for the agent: ``<endpoint>/<domain>`` (the endpoints it connects
    to, or those it listens on when it connects nowhere)."""
    endpoints = settings.connect or settings.listen
    return f"{' or '.join(endpoints) or 'no endpoint'}/{settings.domain}"


def starting(answer: Answer | None, alive: Collection[str]) -> str | None:
    """The progress line of a served ``answer`` whose workers ``alive`` are running, or of an
    answer waiting for stale edges' data (its reason: ``net.answer``), or None if the answer is
    not (yet) that the relation is served, or has no worker to start (a measured edge answers
    it directly: its data is there as soon as it is published)."""
    if answer is not None and answer.waiting:
        return answer.reason
    if answer is None or not answer.served or not answer.components:
        return None
    count = len(answer.components)
    running = sum(instance in alive for instance in answer.components)
    return f"planned: {count} component{'s' * (count != 1)}, {running} alive"


class StartWatch(Closing):
    """Follows the agent's answer to ``relation`` and the worker tokens, and calls ``report``
    with the :func:`starting` line each time it changes (on zenoh's threads: ``report`` must
    not block). Close it (or leave its ``with`` block) once the first sample is there. A
    malformed answer or worker key is counted in ``counters["rejected"]`` and logged
    (rate-limited). Each event costs O(1) but the line's O(components); the watch holds
    O(running workers)."""

    def __init__(
        self,
        session: Any,
        keys: KeySpace,
        relation: RelationId,
        report: Callable[[str], None],
    ) -> None:
        self._keys = keys
        self._relation = relation
        self._report = report
        self._lock = threading.Lock()
        self._answer: Answer | None = None
        self._tokens: Counter[str] = Counter()
        """Worker tokens held, by instance (a restarted worker's new token may come before
        its old one goes)."""
        self._said: str | None = None
        self.counters: Counter[str] = Counter({"rejected": 0, "internal_errors": 0})
        """Answers and worker keys refused as malformed; handler failures."""
        self._closed = threading.Event()
        take_answer = self._guarded(self._take_answer)
        self._answers = session.declare_subscriber(
            keys.answer(relation), lambda sample: take_answer(sample.payload.to_bytes())
        )
        self._workers = session.liveliness().declare_subscriber(
            keys.all_workers(), self._guarded(self._on_worker), history=True
        )
        # An answer published before (another application asks the same): ask for it.
        wanted = [(keys.answer(relation), take_answer, lambda: self._answer is not None)]
        self._fetcher = threading.Thread(
            target=fetch_until_satisfied, args=(session, wanted, self._closed), daemon=True
        )
        self._fetcher.start()

    def _guarded(self, handler: Callable[[Any], None]) -> Callable[[Any], None]:
        """``handler`` never raising into zenoh's thread (``net.logs.guarded``)."""
        return logs.guarded(handler, self.counters, log, str(self._relation))

    def _take_answer(self, payload: bytes) -> None:
        try:
            answer = parse_answer(payload)
        except AnswerError as exc:
            logs.count_problem(self.counters, "rejected", log, "rejected answer: %s", exc)
            return
        with self._lock:
            self._answer = answer
            self._say()

    def _on_worker(self, sample: Any) -> None:
        token = self._keys.parse_token("worker", str(sample.key_expr))
        if isinstance(token, KeyRejection):
            logs.count_problem(
                self.counters,
                "rejected",
                log,
                "rejected worker key %r: %s",
                token.key,
                token.reason,
            )
            return
        with self._lock:
            if str(sample.kind) == "SampleKind.PUT":
                self._tokens[token.name] += 1
            elif self._tokens[token.name] > 1:
                self._tokens[token.name] -= 1
            else:
                del self._tokens[token.name]
            self._say()

    def _say(self) -> None:
        """Under ``_lock``: report the line if it changed."""
        line = starting(self._answer, self._tokens.keys())
        if line is not None and line != self._said and not self._closed.is_set():
            self._said = line
            self._report(line)

    def close(self) -> None:
        """Stop reporting and listening; a second call does nothing."""
        with self._lock:
            if self._closed.is_set():
                return
            self._closed.set()
        self._fetcher.join(timeout=1.0)
        self._answers.undeclare()
        self._workers.undeclare()
