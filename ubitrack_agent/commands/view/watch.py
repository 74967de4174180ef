"""The live view's zenoh side: a thread that, every ``every_s`` seconds, asks the agent for its
status (``<root>/agent/status``, as ``ubitrack status`` does) and the workers for their
counters, subscribes to the key of each relation the agent serves, turns what arrived there
since the last poll into one point of the relation's series (rate, median latency) and asks a
simulated world's ground truth (``<root>/truth/<from>/<to>?t=<ns>``, ``ubitrack sim world``)
for the newest sample's time, for its error. It keeps the latest
:class:`~ubitrack_agent.commands.view.snapshot.Snapshot` for the HTTP side, and hands each
status to its :class:`~ubitrack_agent.commands.view.frame_watch.FrameWatch` (the 3D view's
relations).

The view subscribes with plain subscribers and declares no query token: it is no application,
so watching never changes what the agent plans. Zenoh's callbacks only queue what arrives;
everything else runs on the view's own thread."""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import Counter
from typing import Any

from ubitrack_agent.commands.status import worker_statuses
from ubitrack_agent.commands.view.frame_watch import FrameWatch
from ubitrack_agent.commands.view.series import Period, Series, position_error_mm
from ubitrack_agent.commands.view.snapshot import (
    Snapshot,
    StatusError,
    enrich,
    output_rates,
    parse_status,
    relation_rows,
    watched_relations,
)
from ubitrack_agent.core.codec import decode
from ubitrack_agent.core.errors import MeasurementError
from ubitrack_agent.core.measurements import Measurement
from ubitrack_agent.net import logs
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.time_queries import fetch_at
from ubitrack_agent.net.transport import fetch_latest

log = logging.getLogger("ubitrack.view")

QUERY_TIMEOUT_S = 0.5
"""Longest wait for the agent's status and the workers' counters at each poll."""

TRUTH_TIMEOUT_S = 0.3
"""Longest wait for a ground-truth answer."""

TRUTH_RETRY_S = 10.0
"""After a relation's ground truth went unanswered, how long before it is asked again: most
relations of a real setup have none, and each poll should not wait for it."""


class RelationWatch:
    """One served relation: its subscriber, what arrived since the last poll, its series."""

    def __init__(self, session: Any, keys: KeySpace, relation: RelationId, length: int) -> None:
        self.relation = relation
        self.key = keys.relation(relation)
        self.truth_key = keys.truth(relation.source, relation.target)
        self.series = Series(length)
        self.truth: bool | None = None
        """Whether the ground truth answered when last asked (None: not asked yet)."""
        self.truth_retry_at = 0.0
        self._arrivals: queue.SimpleQueue[tuple[int, bytes]] = queue.SimpleQueue()
        self._subscriber = session.declare_subscriber(self.key, self._arrived)

    def _arrived(self, sample: Any) -> None:
        # on zenoh's thread: note the arrival time and queue, nothing more
        self._arrivals.put((time.time_ns(), sample.payload.to_bytes()))

    def drain(self, counters: Counter[str]) -> Period:
        """What arrived since the last call; a payload that is no measurement is counted
        (``undecodable_samples``) and left out."""
        period = Period()
        while True:
            try:
                arrival_ns, payload = self._arrivals.get_nowait()
            except queue.Empty:
                return period
            try:
                sample = decode(payload)
            except MeasurementError as exc:
                logs.count_problem(counters, "undecodable_samples", log, "%s: %s", self.key, exc)
                continue
            period.add(arrival_ns, sample, timed=not self.relation.static)

    def as_json(self, now_ns: int) -> dict[str, Any]:
        """The relation's description and series, as ``/series.json`` serves them."""
        relation = self.relation
        return {
            "key": self.key,
            "from": relation.source,
            "to": relation.target,
            "type": relation.type,
            "kind": relation.kind,
            "truth": self.truth,
            **self.series.as_json(now_ns),
        }

    def close(self) -> None:
        self._subscriber.undeclare()


class Watcher:
    """Polls and watches (see the module docstring) on a thread of its own; :attr:`snapshot`
    is always the latest complete picture."""

    def __init__(
        self,
        session: Any,
        keys: KeySpace,
        patterns: dict[str, str],
        every_s: float = 1.0,
        history_s: float = 120.0,
    ) -> None:
        self.session = session
        self.keys = keys
        self.patterns = patterns
        self.every_s = every_s
        self.length = max(1, round(history_s / every_s))
        self.counters: Counter[str] = Counter()
        self.snapshot = Snapshot(time.time_ns(), None, "no answer asked for yet")
        self._watches: dict[str, RelationWatch] = {}
        self.frame_watch = FrameWatch(session, keys, self.counters)
        """The live spatial relations, for the 3D view (:mod:`.frame_watch`)."""
        self._workers: dict[str, dict[str, Any]] | None = None
        self._last = time.monotonic()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True, name="view-watch")

    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        for watch in self._watches.values():
            watch.close()
        self._watches.clear()
        self.frame_watch.close()

    def _run(self) -> None:
        poll = logs.guarded(self.poll, self.counters, log, "view poll")
        while not self._stop.is_set():
            started = time.monotonic()
            poll()
            self._stop.wait(max(0.0, self.every_s - (time.monotonic() - started)))

    def poll(self) -> None:
        """One period: the agent's status, the workers' counters, the relations' points."""
        now = time.monotonic()
        seconds, self._last = now - self._last, now
        status, problem = self._status()
        statuses = worker_statuses(self.session, self.keys, QUERY_TIMEOUT_S)
        workers = {instance: worker["counters"] for instance, worker in statuses.items()}
        latencies = {instance: worker["latency_ms"] for instance, worker in statuses.items()}
        rates = {} if self._workers is None else output_rates(self._workers, workers, seconds)
        self._workers = workers
        if status is not None:  # without one, keep watching what was served
            self._follow(watched_relations(status, self.keys))
            self.frame_watch.follow(status)
        now_ns = time.time_ns()
        for watch in self._watches.values():
            period = watch.drain(self.counters)
            watch.series.add(now_ns, period, seconds, self._error_mm(watch, period.latest))
        self.snapshot = Snapshot(
            taken_ns=now_ns,
            status=None
            if status is None
            else enrich(status, workers, rates, self.patterns, latencies),
            problem=problem,
            rates=rates,
            relations=relation_rows(
                status or {}, {name: watch.as_json(now_ns) for name, watch in self._watches.items()}
            ),
            counters=dict(self.counters),
        )

    def _status(self) -> tuple[dict[str, Any] | None, str | None]:
        key = self.keys.agent_status()
        replies = fetch_latest(self.session, key, timeout=QUERY_TIMEOUT_S)
        if not replies:
            return None, f"no agent answers on {key}"
        try:
            return parse_status(replies[0]), None
        except StatusError as exc:
            logs.count_problem(self.counters, "malformed_statuses", log, "%s: %s", key, exc)
            return None, str(exc)

    def _follow(self, wanted: dict[str, RelationId]) -> None:
        """Watch exactly the relations ``wanted``: subscribe to new ones, drop the others."""
        for name in [name for name in self._watches if name not in wanted]:
            self._watches.pop(name).close()
        for name, relation in wanted.items():
            if name not in self._watches:
                self._watches[name] = RelationWatch(self.session, self.keys, relation, self.length)

    def _error_mm(self, watch: RelationWatch, sample: Measurement | None) -> float | None:
        """The distance of ``sample`` from the ground truth at its time, if a simulated world
        answers for the relation (asked again only after ``TRUTH_RETRY_S`` when it did not)."""
        if sample is None or time.monotonic() < watch.truth_retry_at:
            return None
        try:
            answer = fetch_at(self.session, watch.truth_key, sample.timestamp_ns, TRUTH_TIMEOUT_S)
            truth = decode(answer)
        except (ValueError, LookupError, TimeoutError):  # no answer, an error reply, bad bytes
            watch.truth, watch.truth_retry_at = False, time.monotonic() + TRUTH_RETRY_S
            return None
        watch.truth = True
        return position_error_mm(sample, truth)
