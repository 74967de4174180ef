"""Zenoh building blocks shared by providers, workers and applications.

:class:`LatestValuePublisher` publishes samples on a key and answers queries on the same key
with the latest one, so a subscriber that starts late (a worker started after a calibration
database announced its static edges) gets the current value at once with a ``get``. This is
the role of a latched topic; zenoh's own ``AdvancedPublisher`` cache does the same but is
still marked unstable in zenoh-python. Given an ``at`` function, it also answers a query
for the value at a given time (``<key>?t=<ns>``, :mod:`ubitrack_agent.net.time_queries`);
without one such a query gets an ``extrapolation`` error reply (a measured edge has no motion
model).

Each put carries its publisher's next number in its attachment (:mod:`ubitrack_agent.net.sequence`),
and :func:`subscribe_in_bursts` counts the numbers a subscription never saw.

**Nothing waits for a reader.** Every put of the data path (a component's output on its data
key, a relation key, a provider's measured edge) has zenoh's congestion control DROP; only
commands wait (:func:`put_command`). Why, in zenoh 1.x: a message carries its congestion
control, and a router forwards it unchanged (``route_data`` in zenoh's
``zenoh/src/net/routing/dispatcher/pubsub.rs`` copies ``ext_qos``). On each link, a message
whose transmission queue is full waits for room -- the putting thread, or, on a router (a host
manager routing for its containers), the thread receiving from the link it came on, and with
it everything else arriving there. A BLOCK message waits up to ``transport/link/tx/queue/
congestion_control/block/wait_before_close`` (5 s), then zenoh closes the transport of the
link that stayed full (``push_network_message`` in ``io/zenoh-transport/src/common/
pipeline.rs``; ``handle_push_result`` in ``io/zenoh-transport/src/unicast/universal/tx.rs``);
a DROP message waits at most ``.../drop/wait_before_drop`` (``net.config.DROP_WAIT_US``, 10 ms
here), then the queue is marked congested and the next DROP messages on it are dropped at
once, with no wait, until a batch is sent. So one container that stops reading (stopped, hung)
costs the containers that send to it, and every flow of theirs, at most one such wait, and
loses the samples its link could not take, which the numbers count. Until session 27 a
component's data key put with BLOCK, so that a burst between containers arrived whole: a
stopped container then held every flow of each container sending to it for the whole stop, up
to 5 s (``docs/performance.md``, "A stalled reader holds nobody (session 27)"). A reader that
is slow but reads loses what its queue cannot hold beyond the wait, counted, rather than
holding its producers back. A subscriber in the putting session itself is called in the put,
whatever the congestion control (a full ``FifoChannel`` holds the put: zenoh-python's
``FifoChannel`` docstring); components of one container are handed their values without zenoh
(``services.local_wires``).

Threads: a publisher starts none. Its queryable and its matching listener are zenoh callbacks
run on zenoh's own thread (:func:`on_zenoh_thread`), which only hand the query on; the
queries of every publisher of the process are answered by one pool of at most
:data:`ANSWERING_THREADS` threads (:data:`ANSWERS`). Growth: threads O(1) per process (none
until the first query; as many as were answering at once, at most ``ANSWERING_THREADS``),
not O(output keys): a container of a hundred components had two threads per output key, one
answering its queries and one of zenoh-python's for its matching listener
(``docs/performance.md``, "Threads of a container"). :func:`subscribe_in_bursts` has a thread
per subscription (by design), started by one thread of the process (:data:`STARTER`).
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any

import zenoh

from ubitrack_agent.core.errors import ExtrapolationError, NoMotionModel
from ubitrack_agent.net import logs
from ubitrack_agent.net.address import is_misaddressed, put_addressed, reply_addressed
from ubitrack_agent.net.encodings import JSON, MSGPACK
from ubitrack_agent.net.sequence import Gaps, Numbering
from ubitrack_agent.net.thread_pool import ThreadPool
from ubitrack_agent.net.time_queries import error_payload, requested_time

log = logging.getLogger("ubitrack.transport")

FETCH_RETRY_DELAYS = (0.0,) + (0.02,) * 50 + (0.1,) * 20 + (0.5,) * 10
"""Seconds between attempts to fetch current values after subscribing: every 20 ms for a
second, then less often, for 8 s in all. Links come up in the background after ``zenoh.open``,
and an upstream worker started at the same moment computes its static result a little later."""


INPUT_CHANNEL_CAPACITY = 4096
"""Samples zenoh queues for :func:`subscribe_in_bursts` before it holds the sender back; also
the most one burst hands on."""


STARTER = ThreadPool("input-starter", 1)
"""Starts the threads of :func:`subscribe_in_bursts` in the order asked, one at a time, off
the thread subscribing (``net.thread_pool``: started with the first, then kept)."""


ANSWERING_THREADS = 8
"""Most threads answering queries at once in a process (:data:`ANSWERS`). A query for a time
may wait: for a worker's lock (``services.worker.ANSWER_TIMEOUT_S``, 150 ms), then for its
inputs' producers, asked the same question in turn (up to ``UPSTREAM_TIMEOUT_S`` each); a
chain of components in one process asked for a time beyond their samples holds a thread per
link while the next answers. A query arriving while all are busy waits for one (its asker's
own timeout bounds that)."""

ANSWERS = ThreadPool("answers", ANSWERING_THREADS)
"""The threads answering the queries of every :class:`LatestValuePublisher` of the process:
started one at a time, only when a query comes while none is idle, then kept
(``net.thread_pool``). Not zenoh's thread (zenoh-python's guide, "Channels and callbacks":
calling zenoh from a callback, or blocking in it, "may lead to deadlocks", and a reply is a
zenoh call; a time query may block, above), and not a container's scheduler
(``services.scheduler``), whose one thread would hold back every component's turns while a
query waited, and would wait on itself where a time query goes upstream to a producer in the
same container."""


def on_zenoh_thread(callback: Callable[[Any], None]) -> zenoh.handlers.Callback:
    """``callback`` as a zenoh handler run on zenoh's own thread: zenoh-python runs a plain
    Python callable on a thread it starts for each declaration (a subscriber, a queryable, a
    query, a matching listener: ``Callback(..., indirect=True)``, its default, which drains a
    channel on a ``threading.Thread`` of its own; ``indirect=False`` calls it where zenoh
    receives: zenoh-python ``src/handlers.rs``, ``python_callback``, and the ``Callback``
    docstring in ``zenoh/handlers.pyi``). Only for rare messages (commands, queries, a static
    edge's value, an answer, a matching status) and a callback that only hands them on: it
    holds zenoh's thread while it waits for Python's lock, and calls no zenoh function
    (zenoh-python's guide, "Channels and callbacks")."""
    return zenoh.handlers.Callback(callback, indirect=False)


def subscribe_in_bursts(
    session: Any,
    key: str,
    deliver: Callable[[list[bytes]], None],
    capacity: int = INPUT_CHANNEL_CAPACITY,
    gaps: Gaps | None = None,
) -> Any:
    """Subscribe to ``key`` and pass the payloads of the samples waiting, oldest first, to
    ``deliver`` as one burst, on a thread of its own; the subscriber is returned, and the
    thread ends when it is undeclared. The thread is started by :data:`STARTER`, so the
    caller does not wait for it to run (``Thread.start`` waits until the new thread holds
    Python's lock: 2-17 ms in a busy container of 80-100 components, on the path adding a
    component; ``docs/performance.md``, "First sample for 100 applications, session 21");
    the samples wait in zenoh's channel meanwhile. Zenoh queues the samples in its own channel
    (``FifoChannel``, without Python's lock; when it is full, zenoh holds the sender back), so
    its receiving thread, which serves every subscription of the session, never runs Python,
    and the thread wakes once for a burst: a consumer that handles the burst on this thread
    takes each sample after one thread hand-off, and a backlog at once
    (``ubitrack_agent.services.worker``, ``docs/performance.md``, "Data path"). ``deliver`` must not
    raise. ``capacity``: the samples zenoh's channel holds (and the most one burst hands on).
    ``gaps``: where the samples this subscription never got are counted (the numbers of
    :mod:`ubitrack_agent.net.sequence`, O(1) a sample)."""
    subscriber = session.declare_subscriber(key, zenoh.handlers.FifoChannel(capacity))
    # The channel itself, not the subscriber: a call on the subscriber while another thread
    # undeclares it fails ("Already mutably borrowed", pyo3's check of the object's use).
    channel = subscriber.handler
    wildcard = "*" in key
    numbers = (gaps or Gaps()).reader(None if wildcard else key)

    def admitted(sample: Any) -> bool:
        """Counted, and not refused as put on another key (``net.address``)."""
        own = str(sample.key_expr) if wildcard else None
        return numbers.take(attachment(sample), own) is not None

    def drain() -> None:
        try:
            for sample in channel:  # blocks without Python's lock; ends when it is closed
                burst = [sample.payload.to_bytes()] if admitted(sample) else []
                while len(burst) < capacity:
                    more = channel.try_recv()
                    if more is None:
                        break
                    if admitted(more):
                        burst.append(more.payload.to_bytes())
                if burst:
                    deliver(burst)
        except zenoh.ZError:  # closed between two samples: "channel is empty and closed"
            pass

    # RuntimeError: "can't create new thread at interpreter shutdown"
    with contextlib.suppress(RuntimeError):
        STARTER.submit(_start, threading.Thread(target=drain, daemon=True, name=f"input {key}"))
    return subscriber


def attachment(sample: Any) -> bytes | None:
    """A sample's attachment as bytes (a publisher's number: :mod:`ubitrack_agent.net.sequence`),
    or None."""
    found = sample.attachment
    return None if found is None else found.to_bytes()


def _start(thread: threading.Thread) -> None:
    """Start ``thread`` (on :data:`STARTER`); nothing while the interpreter ends."""
    with contextlib.suppress(RuntimeError):
        thread.start()


class LatestValuePublisher:
    """A publisher whose latest payload is also served on its key's queryable; its puts drop
    on a full link (module docstring, "Nothing waits for a reader")."""

    def __init__(
        self,
        session: Any,
        key: str,
        at: Callable[[int], bytes] | None = None,
        counters: Counter[str] | None = None,
        encoding: zenoh.Encoding = MSGPACK,
        listening: Callable[[], None] | None = None,
    ) -> None:
        self.key = key
        self._encoding = encoding
        """What the payloads are (``net.encodings``): measurements unless told otherwise."""
        self._at = at
        """The encoded value at a given time, or a typed error (``net.time_queries.ERRORS``)."""
        self.counters: Counter[str] = Counter() if counters is None else counters
        """``internal_errors``: queries that could not be answered (logged, rate-limited);
        ``rejected_queries``: queries for a time that is no timestamp. Given ``counters`` (a
        worker's), it counts there."""
        self._latest: bytes | None = None
        self._listening = listening
        """Called (on zenoh's thread; it must not block) when a subscriber appears."""
        self.first_put_ns: int | None = None
        """When the first payload was put (wall clock): the first sample on its key."""
        self._numbering = Numbering(key)
        """The number each put carries (:mod:`ubitrack_agent.net.sequence`): a reader counts
        the samples it never got."""
        self._publisher = session.declare_publisher(
            key, encoding=encoding, congestion_control=zenoh.CongestionControl.DROP
        )
        self._state = threading.Lock()
        """Guards :attr:`_putting` and :attr:`_undeclared`, held only between zenoh calls."""
        self._putting = 0
        """Puts running: zenoh's publisher (a pyo3 object) refuses to be undeclared while
        another thread's put runs ("Already borrowed"; a worker rewires its outputs on its
        control thread while its data thread puts), so the last of them undeclares it."""
        self._undeclared = False
        self._matching = False
        """Whether a subscriber listens, as zenoh last told the matching listener (asking
        zenoh costs about 8 us)."""
        self._listener = self._publisher.declare_matching_listener(
            on_zenoh_thread(logs.guarded(self._on_matching, self.counters, log, key))
        )
        if self._publisher.matching_status.matching:  # one already listening: no change told
            self._matching = True
        self._answer = logs.guarded(self._reply_and_finish, self.counters, log, key)
        """:meth:`_reply_and_finish` made total: a failed reply (the querier gone) or a fault is
        counted (``internal_errors``) and logged, and the next query is answered."""
        self._queryable = session.declare_queryable(key, on_zenoh_thread(self._on_query))

    def put(self, payload: bytes) -> None:
        """Keep ``payload`` as the latest (answered to queries) and publish it. Put even while
        the matching listener has not told of a subscriber: zenoh routes by the subscriptions
        it knows, and tells the listener later (a subscriber declared just before a sample on
        the same link gets the sample, and its matching news after it)."""
        self._latest = payload
        with self._state:
            if self._undeclared:
                return  # rewired away meanwhile: the routes of its next output know
            self._putting += 1
        try:
            self._publisher.put(payload, attachment=self._numbering.next())
        finally:
            with self._state:
                self._putting -= 1
                last = self._undeclared and self._putting == 0
            if last:  # undeclared while this put ran: the undeclare was left to it
                self._publisher.undeclare()
        if self.first_put_ns is None:
            self.first_put_ns = time.time_ns()

    def _on_matching(self, status: Any) -> None:
        self._matching = bool(status.matching)
        if self._matching and self._listening is not None:
            self._listening()

    @property
    def matching(self) -> bool:
        """Whether a subscriber currently listens to this key (zenoh's matching status, as
        its listener last reported it)."""
        return self._matching

    def _on_query(self, query: Any) -> None:
        """On zenoh's thread: hand ``query`` to :data:`ANSWERS` (a queue's put; a thread
        started only if none is idle). While the interpreter ends, no thread starts and the
        query goes unanswered (zenoh tells its asker it is finished)."""
        # RuntimeError: "can't create new thread at interpreter shutdown"
        with contextlib.suppress(RuntimeError):
            ANSWERS.submit(self._answer, query)

    def _reply_and_finish(self, query: Any) -> None:
        """On a thread of :data:`ANSWERS`: answer ``query``, then finish it at once (zenoh
        sends its final message when the query is dropped)."""
        with query:
            self._reply(query)

    def _reply(self, query: Any) -> None:
        try:
            timestamp_ns = requested_time(query.parameters)
            if timestamp_ns is not None and self._at is None:
                raise NoMotionModel("a measured edge answers its latest value only")
        except ValueError as exc:  # ExtrapolationError is one
            if not isinstance(exc, ExtrapolationError):
                logs.count_problem(self.counters, "rejected_queries", log, "%s: %s", self.key, exc)
            query.reply_err(error_payload(exc))
            return
        if timestamp_ns is None:
            latest = self._latest
            if latest is not None:
                reply_addressed(query, self.key, latest, self._encoding)
            return
        try:
            payload = self._at(timestamp_ns)
        except (ValueError, LookupError, TimeoutError) as exc:
            query.reply_err(error_payload(exc))
            return
        reply_addressed(query, self.key, payload, self._encoding)

    def undeclare(self) -> None:
        """Undeclare the listener, the queryable and the publisher (a query being answered
        still gets its reply; a put running on another thread finishes and undeclares the
        publisher after it: no thread waits for another's zenoh call; later puts are
        dropped)."""
        self._listener.undeclare()
        self._queryable.undeclare()
        with self._state:
            self._undeclared = True
            now = self._putting == 0
        if now:
            self._publisher.undeclare()


def put_command(session: Any, key: str, payload: str | bytes) -> None:
    """Put a command (a control command to a worker) so that a busy link delays it instead of
    dropping it: zenoh's default for a put drops a message the transmission queue cannot take
    at once, and a lost rewire leaves a relation without data. Its attachment names ``key``
    (``net.address``)."""
    put_addressed(
        session,
        key,
        payload,
        encoding=JSON,
        congestion_control=zenoh.CongestionControl.BLOCK,
        priority=zenoh.Priority.INTERACTIVE_HIGH,
    )


def fetch_latest(session: Any, key: str, timeout: float = 1.0) -> list[bytes]:
    """Payloads the queryables on ``key`` hold now (empty if none answers); a reply whose
    attachment names another key than its own (``net.address``) is left out."""
    payloads = []
    for reply in session.get(key, timeout=timeout):
        if reply.ok is not None and not is_misaddressed(reply.ok):
            payloads.append(reply.ok.payload.to_bytes())
    return payloads


def fetch_until_satisfied(
    session: Any,
    wanted: Sequence[tuple[str, Callable[[bytes], None], Callable[[], bool]]],
    stop: threading.Event,
    delays: Sequence[float] = FETCH_RETRY_DELAYS,
) -> None:
    """For each ``(key, deliver, satisfied)``, fetch the key's latest value and ``deliver`` it,
    retrying after each of ``delays`` until ``satisfied()`` or ``stop`` is set.

    Run it on a thread of its own: never from a zenoh callback.
    """
    for delay in delays:
        if stop.wait(delay):
            return
        pending = [(key, deliver) for key, deliver, satisfied in wanted if not satisfied()]
        if not pending:
            return
        for key, deliver in pending:
            for payload in fetch_latest(session, key, timeout=0.5):
                deliver(payload)
