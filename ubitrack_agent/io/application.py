"""Application API: ask for a spatial relationship and keep receiving it.

::

    keys = KeySpace(settings.key_prefix)
    with (
        open_session(settings) as session,
        Relation(session, keys, RelationId("C", "A", "6D")) as relation,
    ):
        first = relation.wait_for(timeout=5.0)          # next sample, event-driven
        for pose in relation:                           # iterator form, blocks per sample
            ...
        relation.lookup(t_ns)                           # interpolated, or after the
                                                        # newest sample predicted
        relation.predict(time.time_ns() + 20_000_000)   # where at display time (producer's
                                                        # filter, <= core.timeline.MAX_AHEAD_NS)
    # leaving the block withdraws the query (as relation.close() does)

Declaring the query token ``<root>/query/...`` tells the agent what to compute; samples arrive
on the stable key ``<root>/relation/...``, which stays the same whenever the agent rewires the
data flow behind it. Every payload is validated; bad ones are counted in ``rejected``, and
samples stamped more than ``core.timeline.MAX_FUTURE_NS`` ahead of this host's clock in
``rejected_future``: one future sample would otherwise stay :meth:`Relation.latest` until the
clock reached it. :attr:`Relation.counters` holds these and the other counts of samples not
used (``dropped_stale``: older than every sample held; ``out_of_order``, below; ``missed``:
samples the producer put that never came, dropped by zenoh on a full link on the way, counted
from the numbers the samples carry, ``net.sequence``, and not logged; ``misaddressed``:
samples and answers whose attachment names another key than the one they came on, which zenoh
delivered here, ``net.address``; ``internal_errors``); the others are logged rate-limited.

A dynamic relation's stream runs forward in time: the callback, the iterator and
:meth:`Relation.wait_for` get only samples stamped after every sample received before. One
stamped earlier, or the same instant again (when the agent moves the relation from one flow to
another, the new flow's first output may be older than the old flow's last), is kept for
:meth:`Relation.lookup` but not passed on, and counted ``out_of_order``: a renderer never
draws a pose older than one it drew.

A relation's value at a given time (``lookup``, ``predict``) comes from the samples held where
they surround the time, and otherwise from the producer, asked with a query on the relation
key (``net.time_queries``): a fusion filter answers from its motion model up to
``core.timeline.MAX_AHEAD_NS`` (100 ms) after its newest measurement, and a flow without one
refuses (``ExtrapolationError``). Errors are typed: ``NoDataError`` (nothing yet, or no
producer answering), ``ExtrapolationError`` (a time it cannot answer), ``TimeoutError``.

``RelationId(..., static=True, recalibrate=True)`` asks to calibrate a static relation again
(after remounting a target): the agent computes it from the dynamic inputs while ignoring the
measured static edges between its two frames (a stored calibration), on relation and progress
keys of its own, while the plain static relation keeps serving the stored value.

Why nothing arrives: the active agent answers each query (``net.answer``: the flow serving
it, or why none can), kept in :attr:`Relation.answer`, and the answer ends a wait as soon as
it comes (issue 31): while no sample has come, :meth:`Relation.wait_for` and
:meth:`Relation.get` raise :class:`UnsolvedRelation` with the planner's reason the moment the
agent answers that it cannot serve the relation, and :class:`NoAgent` once no agent has been
active on the domain for :data:`NO_AGENT_AFTER_S` (:meth:`Relation.verdict`), whatever their
timeout. ``Relation(..., keep_waiting=True)`` waits on instead, for a relation that may become
servable (its sensors still starting, the agent not yet up); its waits then end only at their
timeout, with the same exceptions, or a plain ``TimeoutError`` if the agent serves the
relation but no sample came (the two are subclasses of it). ``ubitrack_agent.io.waiting``
says what a flow being started has done so far ("planned: 3 components, 1 alive") and which
announced frame a mistyped name may have meant.

A static relation computed from dynamic inputs (a calibration) also reports its progress
(``ubitrack_agent.net.progress``): :attr:`Relation.progress` is the latest report, and
:meth:`Relation.wait_for` raises :class:`NotStatic` when the inputs show that the relation
moves, instead of waiting for an average that would mean nothing.
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
import uuid
from collections import Counter, deque
from collections.abc import Callable, Iterator
from typing import Any

from ubitrack_agent.core import MEASUREMENT_TYPES, Measurement, MeasurementError, decode
from ubitrack_agent.core.errors import ExtrapolationError, NoDataError
from ubitrack_agent.core.timeline import SampleBuffer, ahead_of_clock
from ubitrack_agent.net import logs
from ubitrack_agent.net.address import is_misaddressed, tag
from ubitrack_agent.net.answer import Answer, AnswerError, parse_answer
from ubitrack_agent.net.config import default_host_name
from ubitrack_agent.net.keys import KeySpace, RelationId, validate_key_chunks
from ubitrack_agent.net.lifecycle import Closing
from ubitrack_agent.net.progress import Progress, ProgressError, parse_progress
from ubitrack_agent.net.sequence import Gaps
from ubitrack_agent.net.time_queries import fetch_at
from ubitrack_agent.net.transport import attachment, fetch_until_satisfied

log = logging.getLogger("ubitrack.application")

_TYPES_BY_SRG: dict[str, tuple[type[Measurement], ...]] = {}
for _cls in MEASUREMENT_TYPES.values():
    _TYPES_BY_SRG[_cls.SRG_TYPE] = (*_TYPES_BY_SRG.get(_cls.SRG_TYPE, ()), _cls)


class NotStatic(RuntimeError):
    """A static relation was asked for, but its inputs move more than their noise explains;
    ``progress`` holds the report (its ``motion`` says how far)."""

    def __init__(self, relation: RelationId, progress: Progress) -> None:
        moved = progress.motion or {}
        super().__init__(
            f"{relation} is not static: its estimate moved "
            f"{_describe_motion(moved)} more than the measurements' noise explains"
        )
        self.progress = progress


NO_AGENT_AFTER_S = 1.5
"""Seconds without an active agent's token after which a wait ends with :class:`NoAgent`
(unless the relation keeps waiting): on a working network the token arrives with the first
link, within milliseconds of the session opening."""


def _no_sample(relation: RelationId, timeout: float | None) -> str:
    """The start of the message: the time-out that ended the wait, or only the relation when
    the wait ended before it (``timeout`` None)."""
    return str(relation) if timeout is None else f"no sample of {relation} within {timeout} s"


class UnsolvedRelation(TimeoutError):
    """No sample came because the agent cannot serve the relation; ``reason`` is the planner's
    explanation (``"no provider announces frame(s) X"``, ...), ``cause`` says it in a clause.
    ``timeout`` is None when the answer ended the wait before its timeout."""

    def __init__(self, relation: RelationId, timeout: float | None, reason: str) -> None:
        self.timeout = timeout
        self.reason = reason
        self.cause = f"the agent cannot serve it: {reason}"
        super().__init__(f"{_no_sample(relation, timeout)}: {self.cause}")


class NoAgent(TimeoutError):
    """No sample came and no agent is active on the domain to plan the relation; ``cause``
    says it in a clause. ``timeout`` is None when the wait ended before its timeout."""

    def __init__(self, relation: RelationId, timeout: float | None, root: str) -> None:
        self.timeout = timeout
        self.cause = (
            f"no agent is active on {root} (is `ubitrack agent` running, with the same "
            "--domain and network settings?)"
        )
        super().__init__(f"{_no_sample(relation, timeout)}: {self.cause}")


def _describe_motion(motion: dict[str, Any]) -> str:
    parts = []
    if isinstance(motion.get("translation"), float):
        parts.append(f"{motion['translation'] * 1000:.1f} mm")
    if isinstance(motion.get("rotation"), float):
        parts.append(f"{math.degrees(motion['rotation']):.2f} deg")
    return " and ".join(parts) or "by"


def default_application_id() -> str:
    return f"app-{os.getpid()}-{uuid.uuid4().hex[:8]}"


class Relation(Closing):
    """A subscription to one queried relationship (see the module docstring).

    A context manager: ``with Relation(...) as relation:`` closes it on leaving the block.
    ``keep_waiting``: whether a wait goes on to its timeout when the agent answers that it
    cannot serve the relation, or no agent is there (:meth:`verdict`).
    """

    def __init__(
        self,
        session: Any,
        keys: KeySpace,
        relation: RelationId,
        application: str | None = None,
        callback: Callable[[Measurement], None] | None = None,
        history: int = 256,
        queue_size: int = 1024,
        host: str | None = None,
        host_labels: frozenset[str] = frozenset(),
        keep_waiting: bool = False,
    ) -> None:
        self.relation = relation
        self.keep_waiting = keep_waiting
        self.host = validate_key_chunks(host or default_host_name(), single_chunk=True)
        """The machine this application runs on (default: its host name), named in the query:
        the agent places the relation's last hop near it when that saves a network crossing
        (on a host with every one of ``host_labels``, if given)."""
        self.key = keys.relation(relation)
        self._session = session
        self.application = validate_key_chunks(
            application or default_application_id(), single_chunk=True
        )
        self.counters: Counter[str] = Counter(
            dict.fromkeys(
                (
                    "rejected",
                    "rejected_future",
                    "dropped_stale",
                    "out_of_order",
                    "missed",
                    "misaddressed",
                    "internal_errors",
                ),
                0,
            )
        )
        """Samples and reports not used, by reason (see the module docstring)."""
        self._expected = _TYPES_BY_SRG.get(relation.type, ())
        self._buffer = SampleBuffer(static=relation.static, history=history)
        self._lock = threading.Condition()
        self._received = 0
        self._callback = callback
        self._queue: deque[Measurement] = deque(maxlen=queue_size)
        """Samples not yet taken by :meth:`get` (the oldest dropped when full), under
        ``_lock``: one lock per sample, where a ``queue.Queue`` took three more when full."""
        receive = self._guarded(self._receive)
        numbers = Gaps().reader(self.key)

        def take(sample: Any) -> None:  # on the subscriber's one thread
            missed = numbers.take(attachment(sample))
            if missed is None:  # put on another key, delivered here (net.address)
                self._count("misaddressed", "refused a sample put on another key")
                return
            if missed:
                self.counters["missed"] += missed
            receive(sample.payload.to_bytes())

        self._subscriber = session.declare_subscriber(self.key, take)
        self.progress: Progress | None = None
        """The latest progress report of a static relation computed over time, or None."""
        self.progress_at: float | None = None
        """When (``time.monotonic()``) it arrived: a report that stops coming is from a flow
        the agent has replaced (by a stored value, say)."""
        self.answer: Answer | None = None
        """The active agent's latest answer to this query (``net.answer``), or None."""
        self._root = keys.root
        self._agents: set[str] = set()
        self._agentless_since = time.monotonic()
        """Since when no active agent's token is known (while ``_agents`` is empty)."""
        answer_key = keys.answer(relation)
        receive_answer = self._guarded(self._receive_answer)

        def take_answer(sample: Any) -> None:
            if is_misaddressed(sample):
                self._count("misaddressed", "refused an answer put on another key")
                return
            receive_answer(sample.payload.to_bytes())

        self._answer_subscriber = session.declare_subscriber(answer_key, take_answer)
        self._agent_watch = session.liveliness().declare_subscriber(
            keys.all_active_agents(), self._on_agent, history=True
        )
        wanted = [
            (self.key, receive, lambda: self._received > 0),
            (answer_key, receive_answer, lambda: self.answer is not None),
        ]
        self._progress_subscriber = None
        if relation.static:
            progress_key = keys.progress(relation)
            receive_progress = self._guarded(self._receive_progress)
            progress_tag = tag(progress_key)

            def take_progress(sample: Any) -> None:
                if is_misaddressed(sample, progress_tag):
                    self._count("misaddressed", "refused a progress report put on another key")
                    return
                receive_progress(sample.payload.to_bytes())

            self._progress_subscriber = session.declare_subscriber(progress_key, take_progress)
            wanted.append((progress_key, receive_progress, lambda: bool(self.progress)))
        self._token = session.liveliness().declare_token(
            keys.query(relation, self.application, self.host, host_labels)
        )
        self._closed = threading.Event()
        # A static result published before this application started: ask for it.
        self._fetcher = threading.Thread(
            target=fetch_until_satisfied, args=(session, wanted, self._closed), daemon=True
        )
        self._fetcher.start()

    @property
    def rejected(self) -> int:
        """Samples and progress reports refused as malformed."""
        return self.counters["rejected"]

    def _guarded(self, handler: Callable[[bytes], None]) -> Callable[[bytes], None]:
        """``handler`` never raising into zenoh's or the fetcher's thread (``net.logs.guarded``)."""
        return logs.guarded(handler, self.counters, log, str(self.relation))

    def _count(self, counter: str, message: str, *details: Any) -> None:
        logs.count_problem(self.counters, counter, log, f"%s: {message}", self.relation, *details)

    def _receive_progress(self, payload: bytes) -> None:
        """Runs on zenoh's thread: keep the latest valid report, wake waiters if it says the
        relation is not static."""
        try:
            progress = parse_progress(payload)
        except ProgressError as exc:
            self._count("rejected", "rejected progress report: %s", exc)
            return
        with self._lock:
            self.progress, self.progress_at = progress, time.monotonic()
            self._lock.notify_all()

    def _receive_answer(self, payload: bytes) -> None:
        """Runs on zenoh's thread: keep the latest valid answer and wake the waiters (one that
        says the relation cannot be served ends their wait: :meth:`verdict`)."""
        try:
            answer = parse_answer(payload)
        except AnswerError as exc:
            self._count("rejected", "rejected answer: %s", exc)
            return
        with self._lock:
            self.answer = answer
            self._lock.notify_all()

    def _on_agent(self, sample: Any) -> None:
        """Runs on zenoh's thread: an active agent's token appeared or went."""
        key = str(sample.key_expr)
        with self._lock:
            if str(sample.kind) == "SampleKind.PUT":
                self._agents.add(key)
            else:
                self._agents.discard(key)
                if not self._agents:
                    self._agentless_since = time.monotonic()
            self._lock.notify_all()

    def verdict(self) -> TimeoutError | None:
        """Why waiting for the first sample is pointless now, as the exception a wait raises
        at once: :class:`UnsolvedRelation` if the agent's answer is that it cannot serve the
        relation (not merely that it has not planned it yet, or waits for data: ``Answer.final``),
        :class:`NoAgent` if no agent
        has been active for :data:`NO_AGENT_AFTER_S`; None while there is reason to wait,
        always with ``keep_waiting``, and once a sample has come (a flowing relation's waits
        run to their timeout, as the workers keep the data flowing while an agent restarts,
        and a flow that lost a sensor may be replanned)."""
        answer = self.answer
        if self.keep_waiting or self._received:
            return None
        if answer is not None and answer.final:
            return UnsolvedRelation(self.relation, None, answer.reason or "")
        if not self._agents and time.monotonic() - self._agentless_since >= NO_AGENT_AFTER_S:
            return NoAgent(self.relation, None, self._root)
        return None

    def _wait(self, ready: Callable[[], bool], timeout: float | None) -> None:
        """Under ``_lock``: return once ``ready()``; raise :meth:`verdict` as soon as there is
        one, :meth:`silence` at ``timeout``. Woken by samples, answers and agent tokens, and
        at the moment a missing agent becomes a verdict."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while not ready():
            verdict = self.verdict()
            if verdict is not None:
                raise verdict
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                raise self.silence(timeout)
            wake = deadline
            if not self._agents and not self.keep_waiting:  # when a missing agent is a verdict
                verdict_at = self._agentless_since + NO_AGENT_AFTER_S
                wake = verdict_at if wake is None else min(wake, verdict_at)
            self._lock.wait(None if wake is None else max(0.0, wake - now))

    def silence(self, timeout: float | None) -> TimeoutError:
        """Why no sample came within ``timeout``, as the exception to raise: the agent's
        reason (:class:`UnsolvedRelation`), no agent (:class:`NoAgent`), or neither."""
        answer = self.answer
        if answer is not None and not answer.served:
            return UnsolvedRelation(self.relation, timeout, answer.reason or "")
        if not self._agents:
            return NoAgent(self.relation, timeout, self._root)
        return TimeoutError(f"no sample of {self.relation} within {timeout} s")

    def _receive(self, payload: bytes) -> None:
        """Runs on zenoh's thread: validate, store, notify; no zenoh calls, no blocking."""
        try:
            sample = decode(payload, expected=self._expected or None)
        except MeasurementError as exc:
            self._count("rejected", "rejected sample: %s", exc)
            return
        self._take(sample)

    def _take(self, sample: Measurement) -> None:
        """A decoded sample: checked against this host's clock, stored, passed on."""
        if ahead_of_clock(sample.timestamp_ns, time.time_ns()):
            self._count("rejected_future", "rejected sample stamped ahead: %d", sample.timestamp_ns)
            return
        with self._lock:
            newest = self._buffer.newest_time()
            if not self._buffer.add(sample):
                self._count("dropped_stale", "dropped sample older than those held")
                return
            if not self.relation.static and newest is not None and sample.timestamp_ns <= newest:
                self._count(
                    "out_of_order",
                    "sample %d not after the newest, %d: kept for lookups, not passed on",
                    sample.timestamp_ns,
                    newest,
                )
                return
            self._received += 1
            self._queue.append(sample)  # the reader lags: the oldest goes
            self._lock.notify_all()
        if self._callback is not None:
            try:
                self._callback(sample)
            except Exception:  # a broken callback must not break zenoh's receive thread
                log.exception("%s: application callback failed", self.relation)

    @property
    def received(self) -> int:
        return self._received

    def latest(self) -> Measurement | None:
        """The newest sample, or None before the first."""
        with self._lock:
            return self._buffer.latest()

    def lookup(self, timestamp_ns: int, timeout: float = 0.2) -> Measurement:
        """The relation at ``timestamp_ns``: interpolated between the samples held (a static
        relation answers its latest value), and after the newest sample :meth:`predict`-ed.
        Raises ``NoDataError`` (no sample yet), ``ExtrapolationError`` (before the samples
        held, or after them where the producer does not predict, or beyond its bound) or
        ``TimeoutError``."""
        with self._lock:
            newest = self._buffer.newest_time()
            if self.relation.static or newest is None or timestamp_ns <= newest:
                return self._buffer.lookup(timestamp_ns)
        try:
            return self.predict(timestamp_ns, timeout)
        except NoDataError as exc:  # samples are held, none at that time
            raise ExtrapolationError(f"after the samples held, and {exc}") from None

    def predict(self, timestamp_ns: int, timeout: float = 0.2) -> Measurement:
        """The relation at ``timestamp_ns`` as its producer answers it (a query on the relation
        key): a fusion filter predicts from its motion model, at most
        ``core.timeline.MAX_AHEAD_NS`` (100 ms) after its newest measurement, and interpolates
        within its recent past; a flow without a motion model answers only within its inputs'
        samples. The renderer's question: where will it be at display time. Raises
        ``ExtrapolationError`` (a time the producer cannot answer), ``NoDataError`` (no
        producer answered within ``timeout`` seconds, or it has no data yet),
        ``TimeoutError`` (the producer was busy) or ``MeasurementError`` (a malformed
        answer)."""
        payload = fetch_at(self._session, self.key, timestamp_ns, timeout)
        value = decode(payload, expected=self._expected or None)
        if value.timestamp_ns != timestamp_ns:
            raise ExtrapolationError(f"{self.relation}: the producer answered another time")
        return value

    def wait_for(self, timeout: float | None = None) -> Measurement:
        """Block until the next sample arrives (the first one if none yet); ``TimeoutError``,
        or :class:`NotStatic` for a static relation whose inputs move."""
        with self._lock:
            seen = self._received
            self._wait(lambda: self._received > seen or self._moving(), timeout)
            if self._received == seen and self.progress is not None:
                raise NotStatic(self.relation, self.progress)
            return self._buffer.latest()

    def _moving(self) -> bool:
        return self.progress is not None and self.progress.not_static

    def __iter__(self) -> Iterator[Measurement]:
        """Samples as they arrive, each after the one before for a dynamic relation (module
        docstring), blocking for each (oldest dropped if the reader lags)."""
        while True:
            yield self.get()

    def get(self, timeout: float | None = None) -> Measurement:
        """The next queued sample; ``TimeoutError`` if none arrives in time, or at once the
        :meth:`verdict` that none will."""
        with self._lock:
            self._wait(lambda: bool(self._queue), timeout)
            return self._queue.popleft()

    def close(self) -> None:
        """Withdraw the query; the agent stops what only this application needed. A second
        call does nothing."""
        if self._closed.is_set():
            return
        self._closed.set()
        self._fetcher.join(timeout=1.0)
        self._token.undeclare()
        self._subscriber.undeclare()
        self._answer_subscriber.undeclare()
        self._agent_watch.undeclare()
        if self._progress_subscriber is not None:
            self._progress_subscriber.undeclare()
