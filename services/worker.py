"""The worker runtime: one OS process runs one pattern instance, wired over zenoh.

Start: ``python -m ubitrack_agent.services.worker --spec '<json>' [zenoh flags]`` (see
:mod:`ubitrack_agent.services.spec`). The worker opens its own zenoh session (explicit endpoints,
multicast off: it opens in milliseconds), takes commands on ``<root>/control/<instance>`` and, for
this process alone, on ``<root>/control/<instance>/<incarnation>`` (subscribed first, before
anything else is declared), subscribes to its input keys, publishes its outputs, answers its
counters on ``<root>/status/<instance>`` and, last, declares the liveliness token
``<root>/worker/<instance>/<incarnation>`` (``<pid>.<nonce>``, new for every run):

* ``{"inputs": [<bindings>]}`` rewires: bindings whose key is unchanged keep their history
  (moved by the change of their ``clock_offset_ns``, if any);
* ``{"parameters": {...}}`` rebuilds the service with new parameters;
* the bindings or parameters the worker already has change nothing (an agent taking over
  sends each worker its whole wiring: a filter is not reset, no subscription renewed);
* ``{"relations": {"<output port>": ["<relation key>", ...]}}`` also publishes an output on the
  stable relation keys of the applications it serves (replacing the previous ones);
* ``{"stop": true}`` ends the run: the agent (directly, or through the host manager that
  started the worker) stops every worker with it; a pool member then rejoins its pool (or
  exits, if its host manager is gone).

A process a host manager started (``--pool-id``; its standard input a pipe from the host
manager) outlives the host manager only once its token is up: one still starting, from its
spawn to its token (importing every service takes seconds on a loaded machine), exits as soon
as the host manager is gone, which it watches from the start of :func:`main`, before any
service is imported (:mod:`ubitrack_agent.services.parent`); one serving keeps running, for a
restarted agent to adopt. A pool member given a group (``net.spec.GroupSpec``) instead of one
specification becomes that container (:mod:`ubitrack_agent.services.container`) and exits when the
container ends.

An input's ``clock_offset_ns`` (``net.spec``) is added to the timestamp of each of its samples
as it is decoded, before anything else uses it: the agent sets it when the component's inputs
come from hosts whose clocks differ (``agent.clocks``), so they are synchronised on the agent's
clock. A query for an input's value at a given time goes upstream at the input's own time.

Zenoh's receiving thread, which serves every subscription of the process, runs no Python for a
sample and is never held up by a computation (``docs/services.md``, "Threads"): each input has
a thread of its own that takes the samples waiting in zenoh's channel at once
(``net.transport.subscribe_in_bursts``) and handles them itself, one thread hand-off per
sample: it decodes each (validated in full, or at level ``WORKER`` for a binding
``from_worker``: ``core.measurements``), synchronises (:mod:`ubitrack_agent.core.timeline`),
computes and publishes; a backlog of one input under load, where nothing holds a sample back,
as one run (:meth:`Worker._on_run`: decoded and, where the service vectorises, computed
together). The worker's state has one lock, held by whichever thread handles: an input's, a
query's for a value at a given time, or the worker thread, which answers status queries and
applies control commands (from zenoh's callbacks, run on zenoh's thread, through a bounded
inbox) and computes the triggers held for the other inputs when their time is up. In a
container (:mod:`ubitrack_agent.services.container`) the container's scheduler
(:mod:`ubitrack_agent.services.scheduler`) takes the worker thread's turns (:meth:`Worker.turn`) for
every component, and its static inputs' samples and its fetches of current values: a component has
no thread of its own.

Handling is total (issue 11): bad input (a sample the codec refuses, one stamped too far ahead
of this host's clock, a control command or specification that is not a bounded JSON object of
the right form) is rejected, logged rate-limited
(:func:`ubitrack_agent.net.logs.rate_limited`) and counted in :data:`COUNTERS`, shown in the
status; so is every path on which a sample is consumed without an output. An unexpected
exception while handling network input is logged with its traceback and counted
(``internal_errors``); it never stops the worker. SIGTERM or SIGINT ends it cleanly, closing
the session.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import json
import logging
import math
import os
import queue
import statistics
import sys
import threading
import time
import uuid
from collections import Counter, defaultdict, deque
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from typing import Any

from ubitrack_agent.core import Measurement, MeasurementError, decode, encode
from ubitrack_agent.core.codec import RUN_MIN, decode_run
from ubitrack_agent.core.errors import (
    ExtrapolationError,
    NoDataError,
    NoMotionModel,
    TooFewCorrespondences,
)
from ubitrack_agent.core.heap import settle_collector
from ubitrack_agent.core.measurements import FULL, MAX_FUTURE_NS, MAX_TIMESTAMP_NS, WORKER
from ubitrack_agent.core.poses import with_static_error
from ubitrack_agent.core.timeline import SampleBuffer
from ubitrack_agent.net import config, logs
from ubitrack_agent.net.address import is_misaddressed, tag
from ubitrack_agent.net.clock import Clock
from ubitrack_agent.net.encodings import JSON, MSGPACK
from ubitrack_agent.net.json_messages import load_object
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.lifecycle import on_termination
from ubitrack_agent.net.progress import Progress
from ubitrack_agent.net.sequence import Gaps
from ubitrack_agent.net.spec import (
    ComponentSpec,
    GroupSpec,
    InputBinding,
    SpecError,
    parse_assignment,
    parse_bindings,
    parse_relations,
    parse_spec,
)
from ubitrack_agent.net.time_queries import fetch_at
from ubitrack_agent.net.transport import (
    FETCH_RETRY_DELAYS,
    LatestValuePublisher,
    fetch_until_satisfied,
    on_zenoh_thread,
    subscribe_in_bursts,
)
from ubitrack_agent.services.expansion import BatchProgress, TimeAccumulator
from ubitrack_agent.services.handover import COUNTERS as HAND_OVER_COUNTERS
from ubitrack_agent.services.handover import Watch
from ubitrack_agent.services.local_wires import (
    Handed,
    LocalSubscription,
    LocalWires,
    deliver,
    finite,
)
from ubitrack_agent.services.parent import Parent
from ubitrack_agent.services.registry import Pushed, Service, lookup
from ubitrack_agent.services.scheduler import Scheduler
from ubitrack_agent.services.spec import (
    check_bindings,
    check_parameters,
    check_relations,
    check_spec,
)
from ubitrack_agent.services.triggers import PendingTriggers, lagging, wait_for

log = logging.getLogger("ubitrack.worker")

INBOX_CAPACITY = 256
"""Control commands waiting for the worker thread; beyond this the oldest are dropped and
counted."""

CONTROL_FIELDS = frozenset({"inputs", "parameters", "relations", "stop"})
"""What a control command may change (see the module docstring)."""
MAX_CONTROL_BYTES = 64 * 1024
"""Largest control command read (a rewire of a dozen bindings takes a kilobyte)."""

MAX_HELD_FOR_STATIC = 64
"""Most triggers held until a static input's first value (about 1 s of a 60 Hz tracker)."""
COUNTERS = {
    "received": "samples received on the input keys",
    "in_runs": "of those, samples handled in a run with others of their input (a backlog taken "
    "at once under load: Worker._on_run)",
    "published": "outputs published",
    "handed_over": "of those, outputs handed as objects to components of the same container "
    "(ubitrack_agent.services.local_wires)",
    "not_sent": "of those, outputs handed over in the container that zenoh did not carry on "
    "their data key: no subscriber outside the process (a relation key is put for an "
    "application listening, as every key: net.transport.LatestValuePublisher)",
    "missed": "samples a dynamic input read over zenoh never got: numbers its producer put "
    "that did not arrive (zenoh dropped them on a full link: net.sequence, net.transport)",
    "misaddressed": "samples and control commands refused as put on another key than the one "
    "they came on (net.address: zenoh delivered them there); logged as a summary every "
    "SUMMARY_S",
    "rejected": "samples the codec refused (garbage, wrong type, NaN, wrong shape)",
    "rejected_future": "samples stamped too far ahead of this host's clock (core.timeline)",
    "rejected_clock": "samples whose timestamp moved by their input's clock offset leaves the "
    "timestamp range",
    "dropped_stale": "samples older than everything their input's buffer holds",
    "superseded": "samples from a subscription that a rewire replaced",
    "buffered": "samples of inputs that do not trigger, kept for the next trigger",
    "stale_triggers": "trigger samples at an instant pending, computed, or before the last",
    "dropped": "triggers dropped: an input had no value at the trigger's time",
    "held_for_static": "triggers held until a static input's first value came (then computed, "
    "or dropped if more than MAX_HELD_FOR_STATIC waited)",
    "not_distinct": "time expansion: correspondence values too close to the last kept",
    "accumulating": "time expansion: fewer correspondences kept than the pattern needs",
    "no_output": "computations that published nothing (an estimate not yet ready)",
    "failed": "computations that failed (degenerate input), or whose result holds NaN or "
    "infinity (not published)",
    "too_few_correspondences": "instants with fewer complete correspondences than the pattern "
    "needs (a feature hidden): expected, logged as a summary every SUMMARY_S",
    "overflow": "control commands and status queries dropped because the inbox was full",
    "rejected_commands": "control commands refused",
    "rewired": "control commands applied",
    "internal_errors": "unexpected exceptions handling network input (logged with traceback)",
    "gated": "asynchronous filter: samples refused by the innovation gate (outliers)",
    "late": "asynchronous filter: samples older than the newest, re-filtered (in the next output)",
    "time_queries": "queries for the value at a given time answered",
    "time_queries_refused": "queries for the value at a given time answered with an error",
    "rejected_queries": "queries for a time that is no timestamp (net.time_queries)",
    **HAND_OVER_COUNTERS,
}
"""The worker's counters (its status), each with what it counts. Every sample received is
``rejected``, ``rejected_future``, ``rejected_clock``, ``dropped_stale``, ``superseded``,
``buffered`` or a trigger; every trigger is ``stale_triggers``, ``dropped``, ``not_distinct``,
``accumulating``, ``failed``, ``no_output`` or publishes (one that came before a static
input's first value is counted ``held_for_static`` first, and ends so once computed): a worker
that receives but does not publish shows why.
For an asynchronous service every sample is a trigger and ends ``gated``, ``late``,
``dropped_stale``, ``failed`` or publishes."""

ANSWER_TIMEOUT_S = 0.15
"""Longest a query for the value at a given time waits for the worker's lock (a thread
handling samples holds it), then it is answered with a time-out."""
UPSTREAM_TIMEOUT_S = 0.1
"""Longest the thread answering such a query waits for an input's producer to answer it."""
CURRENT_TIMEOUT_S = 0.5
"""Longest a new component waits for its dynamic inputs' producers to answer their current
value (:meth:`Worker._fetch_current`; they answer in milliseconds)."""
STATIC_POLL_S = 0.002
"""How often a new component in a container looks whether its static inputs have their values
before it is handed its dynamic inputs' current values (:meth:`Worker._hand_current`)."""
FETCH_TIMEOUT_S = 0.5
"""Longest a static input's producer is waited for to answer its latest value (one attempt of
``net.transport.FETCH_RETRY_DELAYS``)."""
NO_MODEL_S = 1.0
"""How long an input whose producer answered ``no_model`` (a measured edge) or nothing is not
asked again: a renderer asking every frame must not cost the flow a round trip (or a
time-out) per input each time."""
LATENCY_SAMPLES = 64
"""Samples per input whose latency the status's median covers."""
HANDLING_GAIN = 0.05
"""Weight of the latest sample in the running mean of the time to handle one (``handling_us``
in the status)."""
TIME_EVERY = 8
"""One delivery of samples in this many is timed for ``handling_us`` (reading the clock twice
costs a hop in a container about 2 % more)."""
IDLE_S = 1.0
"""Longest the worker thread waits when nothing is due: commands, a trigger held, a stop and
a subscriber appearing for an output read in the container wake it (``Worker.step``); every
0.1 s, it cost an idle container of ten components 2.8 % of a core."""
SUMMARY_S = 10.0
"""Seconds between two summaries of the expected conditions counted (``_summarise``)."""


@dataclass(frozen=True)
class ControlCommand:
    """A control command read and checked in full before any of it is applied."""

    stop: bool = False
    parameters: dict[str, Any] | None = None
    service: Service | None = None
    inputs: tuple[InputBinding, ...] | None = None
    relations: dict[str, tuple[str, ...]] | None = None


class Inbox:
    """A bounded queue from zenoh's callbacks (control commands) and the inputs' threads (a
    wake-up for a trigger held) to the worker thread that drops its oldest item when full
    (counted as ``overflow``; producers racing past the check may each add one more). The
    worker takes everything waiting at once (:meth:`take`). Written on ``queue.SimpleQueue``,
    whose put and get are C calls that block without Python's lock: ``threading.Event`` and
    ``queue.Queue`` run a condition's Python code on both threads for every item handed over
    (issue 12; ``docs/performance.md``, "Data path")."""

    def __init__(
        self, capacity: int, counters: Counter[str], notify: Callable[[], None] | None = None
    ) -> None:
        self._items: queue.SimpleQueue[tuple[Any, ...]] = queue.SimpleQueue()
        self._capacity = capacity
        self._counters = counters
        self._notify = notify
        """Called after each item is put (a container's scheduler then gives the worker a
        turn: ``ubitrack_agent.services.scheduler``)."""

    def put(self, item: tuple[Any, ...]) -> None:
        if self._items.qsize() >= self._capacity:
            try:
                self._items.get_nowait()  # the oldest (the worker may have taken it meanwhile)
            except queue.Empty:
                pass
            else:
                self._counters["overflow"] += 1
        self._items.put(item)
        if self._notify is not None:
            self._notify()

    def take(self, timeout: float) -> list[tuple[Any, ...]]:
        """Every item waiting, oldest first, once one waits or after ``timeout`` (then none)."""
        try:
            items = [self._items.get(timeout=timeout)]
        except queue.Empty:
            return []
        return self._waiting(items)

    def take_waiting(self) -> list[tuple[Any, ...]]:
        """Every item waiting, oldest first, without waiting for one."""
        return self._waiting([])

    def _waiting(self, items: list[tuple[Any, ...]]) -> list[tuple[Any, ...]]:
        get = self._items.get_nowait
        items.extend(get() for _ in range(self._items.qsize()))  # only one thread takes
        return items


@dataclass
class _Input:
    binding: InputBinding
    buffer: SampleBuffer
    subscriber: Any
    expected: tuple[type[Measurement], ...]
    """The measurement types its port takes."""
    level: str
    """Its samples' validation level: ``WORKER`` from a known worker, else ``FULL``."""
    latency: deque[int]
    """Its key's latest latencies (``Worker._latency``)."""
    seen: bool
    """Whether its key's first sample is stamped (``Worker._first_samples``)."""


@dataclass(frozen=True, slots=True)
class _Route:
    """Where an output port's values go: its data key, the publishers of its data key and
    relation keys (the data key's first), and those of its relation keys alone."""

    key: str
    publishers: tuple[LatestValuePublisher, ...]
    relations: tuple[LatestValuePublisher, ...]


class Worker:
    """Runs ``spec`` on an open zenoh ``session`` until :meth:`stop`."""

    def __init__(
        self,
        spec: ComponentSpec,
        session: Any,
        keys: KeySpace,
        pool_counters: Counter[str] | None = None,
        clock: Clock | None = None,
        parent: Parent | None = None,
        wires: LocalWires | None = None,
        container: str | None = None,
        scheduler: Scheduler | None = None,
    ) -> None:
        created_ns = time.time_ns()
        self.spec = spec
        self.container = container
        """The container this component runs in with others (``ubitrack_agent.services.container``),
        if any (shown in status)."""
        self._wires = wires
        """The container's local wires: inputs whose key another component of the container
        produces are handed its values as objects, and outputs read there are handed over
        (``ubitrack_agent.services.local_wires``); zenoh carries an output only where something
        outside the process reads it."""
        self._handed: Handed = []
        """Hand-overs to readers in the container queued under ``_lock``, taken before it is
        released and delivered after (``ubitrack_agent.services.local_wires``)."""
        self._outgoing: deque[
            tuple[tuple[LatestValuePublisher, ...], Measurement | bytes, bytes | None]
        ] = deque()
        """The puts for readers outside the process, in the order the outputs were published
        (queued under ``_lock``), each with its publishers, its value (a measurement, or a
        payload: a progress report) and its payload if encoded already (None for a value
        handed over, checked finite, encoded when put): put by :meth:`_put_outside`. The
        measurement is kept beside its payload for the relation keys' hand-over rules, which
        would decode it again (``services.handover``)."""
        self._put_lock = threading.Lock()
        """Held while the queued puts are put: one thread at a time, so none overtakes another."""
        self._unsent: set[str] = set()
        """Output keys read in the container whose latest value zenoh has not carried (no
        subscriber outside then): sent once one appears (:meth:`_send_unsent`)."""
        self.clock = clock or Clock()
        """This host's clock (``Settings.clock_offset_ms`` applied), for samples stamped
        ahead of it."""
        self._now_ns = time.time_ns if self.clock.offset_ns == 0 else self.clock.now_ns
        """This host's clock read (``time.time_ns`` itself where it has no offset: a Python call
        fewer on every sample)."""
        self._space = spec.expansion == "space"
        self._tolerance_ns = spec.tolerance_ns
        """The specification's, read on every sample (no control command changes them)."""
        self.pool_counters = pool_counters
        """The counters of the pool this process belongs to, if any (shown in status)."""
        self.keys = keys
        self._needed = (*map(keys.provider, spec.required_providers), *spec.required_edges)
        """The liveliness tokens of the providers and the measured edges this component needs:
        a relation key it holds is given up when one leaves (``services.handover``, rule 7)."""
        self._counts: Counter[str] = Counter(dict.fromkeys(COUNTERS, 0))
        """The counters but those counted on every sample (:attr:`counters` adds them)."""
        self._received = self._published = self._handed_over = self._not_sent = 0
        """Those counted on every sample, as integers (a ``Counter``'s increment costs a hop in
        a container about 1 % each); changed under ``_lock`` only."""
        self._gaps = Gaps()
        """Samples its dynamic inputs read over zenoh never got (``missed``: net.sequence)."""
        self._session = session
        self._service_class = lookup(spec.service)
        self._computes_runs = self._service_class.compute_run is not Service.compute_run
        """Whether the service computes a run of instants at once (:meth:`_on_run`)."""
        self._service: Service = self._service_class(spec.parameters)
        self._asynchronous = self._service.asynchronous()
        self._reports_progress = self._new_progress()
        self._accumulator = self._new_accumulator()
        self._pending = PendingTriggers()
        self._held_for_static: deque[tuple[int, _Input | None, Measurement | None]] = deque()
        """Triggers that came before a static input's first value, oldest first: computed
        when it comes (:meth:`_release_held`), so a flow's first outputs use every input."""
        self._summarised, self._summary_due = 0, time.monotonic() + SUMMARY_S
        self._refused_summarised = 0
        self._scheduler = scheduler
        """The container's scheduler, which gives this component its turns (:meth:`turn`)
        and runs its static inputs' samples and its fetches (``ubitrack_agent.services.scheduler``);
        None for a worker on a thread of its own (:meth:`run`)."""
        notify = None if scheduler is None else functools.partial(scheduler.wake, self, self.turn)
        self._inbox = Inbox(INBOX_CAPACITY, self._counts, notify)
        self._lock = threading.Lock()
        """Held while the worker's state is used: by an input's thread handling its samples,
        a query's thread answering for a time, the worker thread (commands, held triggers)."""
        self._wakes_at = -math.inf
        """When the worker thread wakes next unless woken (monotonic; minus infinity while it
        is awake: it looks at the triggers held before it waits again)."""
        self._handling_s = 0.0
        """Running mean of the time to handle a sample (seconds), over every
        :data:`TIME_EVERY` deliveries (the first among them)."""
        self._deliveries = 0
        self._stop = threading.Event()
        self._stopping = False
        """Set with ``_stop`` (:meth:`stop`, :meth:`close`), read on every sample (an attribute,
        not ``Event.is_set``'s call)."""
        self.released = False
        """True when a control command ended the run: the process may serve another component."""
        self._inputs: list[_Input] = []
        self._dynamic: list[SampleBuffer] = []
        """The buffers of the dynamic inputs, in binding order."""
        self._no_model: dict[str, float] = {}
        """Input keys whose producers answered ``no_model``, until when (monotonic)."""
        self._generation = 0
        self._publishers: dict[str, LatestValuePublisher] = {}
        self._hand_overs: dict[str, Watch] = {}
        """Each dynamic relation key's hand-over (``ubitrack_agent.services.handover``)."""
        self._routes: dict[str, list[str]] = {}
        self._out: dict[str, _Route] = {}
        """By output port, where its values go (:meth:`_route_outputs`)."""
        self._progress_routes: dict[str, list[str]] = {}
        self.progress: dict[str, Progress] = {}
        """The latest progress of each static estimate, by output port (shown in status)."""
        self._latency: defaultdict[str, deque[int]] = defaultdict(
            lambda: deque(maxlen=LATENCY_SAMPLES)
        )
        """Per input key, the latest samples' latency (ns): this host's clock when the worker
        takes the sample minus its timestamp (after the input's clock offset); each input
        holds its key's (``_Input.latency``)."""
        self._first_samples: dict[str, int] = {}
        """Per input key, when its first sample was taken (wall clock): O(input keys ever)."""
        self.incarnation = f"{os.getpid()}.{uuid.uuid4().hex[:8]}"
        """Tells this run's token from any other's (``docs/protocol.md``, "Workers")."""
        self._controls = [
            session.declare_subscriber(
                key, on_zenoh_thread(self._guarded(self._control_handler(key)))
            )
            for key in (
                keys.control(spec.instance),
                keys.control_incarnation(spec.instance, self.incarnation),
            )
        ]
        self._route_outputs(spec.relations)
        ask = self._guarded(lambda query: self._inbox.put(("status", query)))
        self._status = session.declare_queryable(keys.status(spec.instance), on_zenoh_thread(ask))
        with self._lock:  # an input's first samples wait until every input is bound
            self._bind(spec.inputs)
        if wires is not None:
            wires.produce(spec.instance, tuple(spec.outputs.values()))
        self._fetch_current()
        declare = functools.partial(
            session.liveliness().declare_token, keys.worker(spec.instance, self.incarnation)
        )
        self._token = declare() if parent is None else parent.serve(declare)
        self.stamps = {"created_ns": created_ns, "ready_ns": time.time_ns()}
        """When this component was created and had declared everything (its token last), on
        the wall clock (issue 28's time to a first sample: ``agent.stamps``)."""

    @property
    def counters(self) -> Counter[str]:
        """Every counter of :data:`COUNTERS`, now (a copy: count in ``_counts``)."""
        counters = self._counts.copy()
        counters["received"] += self._received
        counters["published"] += self._published
        counters["handed_over"] += self._handed_over
        counters["not_sent"] += self._not_sent
        counters["missed"] += self._gaps.missed
        counters["misaddressed"] += self._gaps.misaddressed
        return counters

    @property
    def faults(self) -> int:
        """Unexpected exceptions so far (``internal_errors``)."""
        return self._counts["internal_errors"]

    def _new_progress(self) -> bool:
        """Whether the service reports progress (:meth:`Service.progress` overridden): only
        then is it asked after each computation, which a pattern hop would pay for."""
        return type(self._service).progress is not Service.progress

    def _new_accumulator(self) -> TimeAccumulator | None:
        """The time expansion's accumulator, and for a batch estimate over it (not an
        incremental service, which reports its own) the tracker of its progress."""
        batch = self.spec.expansion == "time" and not self._service_class.INCREMENTAL
        self._batch_progress: dict[str, BatchProgress] | None = {} if batch else None
        """By output port."""
        if self.spec.expansion != "time":
            return None
        return TimeAccumulator(self._service, self.spec.time_expansion)

    # -- wiring ---------------------------------------------------------------------------

    def _bind(self, bindings: tuple[InputBinding, ...]) -> None:
        """Subscribe to ``bindings``, keeping the buffers of inputs whose key (and whether it
        is static) stays the same; under ``_lock``."""
        self._generation += 1
        generation = self._generation
        old = {(item.binding.key, item.binding.static): item for item in self._inputs}
        inputs = []
        for index, binding in enumerate(bindings):
            kept = old.pop((binding.key, binding.static), None)
            if kept is None:
                buffer = SampleBuffer(binding.static)
            else:
                moved = binding.clock_offset_ns - kept.binding.clock_offset_ns
                buffer = kept.buffer.shifted(moved) if moved else kept.buffer
                kept.subscriber.undeclare()
            subscriber = self._subscribe(generation, index, binding)
            expected = self._service_class.INPUTS[binding.port].types
            level = WORKER if binding.from_worker else FULL
            latency, seen = self._latency[binding.key], binding.key in self._first_samples
            inputs.append(_Input(binding, buffer, subscriber, expected, level, latency, seen))
        for item in old.values():
            item.subscriber.undeclare()
        self._inputs = inputs
        if self._wires is not None:  # rebound when a key's producer joins or leaves
            self._wires.reads(self.spec.instance, (binding.key for binding in bindings))
        self._dynamic = [item.buffer for item in inputs if not item.binding.static]
        static = [(index, item) for index, item in enumerate(inputs) if item.binding.static]
        wanted = [
            (
                item.binding.key,
                lambda payload, i=index: self._deliver(generation, i, [payload]),
                lambda buffer=item.buffer: len(buffer) > 0,
            )
            for index, item in static
            if not self._local(item.binding.key)
        ]
        latest = [
            (index, value)
            for index, item in static
            if self._local(item.binding.key)
            and (value := self._wires.latest(item.binding.key)) is not None
        ]
        hands = [
            functools.partial(self._deliver_values, generation, i, [value]) for i, value in latest
        ]
        # A static edge's value may have been published long ago: ask for it, off this thread
        # (which holds no lock: the one binding holds this worker's).
        if self._scheduler is None:
            threading.Thread(target=self._fetch_static, args=(wanted, hands), daemon=True).start()
        else:
            self._scheduler.call(functools.partial(self._ask_static, wanted, hands))

    def _fetch_current(self) -> None:
        """Hand a new component each dynamic input's current value at once, off this thread:
        a value handed over in the container, else its producer's latest (asked once, all
        keys at once: ``net.transport.LatestValuePublisher``). Its first output then comes from
        the newest instant its inputs share, without waiting up to a period for the next one
        (issue 28: a query's first sample). They are handed over once the static inputs have
        their values (fetched at the same time, :meth:`_fetch_static`; at most
        ``CURRENT_TIMEOUT_S``), which an input inverted and composed with them needs. One
        later than a sample the subscription took meanwhile is an older instant: stale,
        ignored. O(dynamic inputs)."""
        generation = self._generation
        local, remote = [], []
        for index, item in enumerate(self._inputs):
            if item.binding.static:
                continue
            key = item.binding.key
            if not self._local(key):
                remote.append((index, key))
            elif (value := self._wires.latest(key)) is not None:
                local.append((index, value))
        if not (local or remote):
            return

        statics = [item.buffer for item in self._inputs if item.binding.static]

        def fetch() -> None:
            asked_at = time.monotonic()
            while any(len(buffer) == 0 for buffer in statics):
                if time.monotonic() - asked_at > CURRENT_TIMEOUT_S or self._stop.wait(0.002):
                    break
            for index, value in local:
                self._deliver_values(generation, index, [value])
            asked = [
                (index, self._session.get(key, timeout=CURRENT_TIMEOUT_S)) for index, key in remote
            ]
            for index, replies in asked:
                for reply in replies:
                    if reply.ok is not None and not is_misaddressed(reply.ok):
                        self._deliver(generation, index, [reply.ok.payload.to_bytes()])

        if self._scheduler is None:
            threading.Thread(target=self._guarded(fetch), daemon=True).start()
        else:
            hand = functools.partial(self._hand_current, generation, local, remote, statics)
            self._scheduler.call(functools.partial(hand, time.monotonic()))

    def _hand_current(
        self,
        generation: int,
        local: list[tuple[int, Measurement]],
        remote: list[tuple[int, str]],
        statics: list[SampleBuffer],
        asked_at: float,
    ) -> None:
        """:meth:`_fetch_current` in a container, on its scheduler's thread
        (``ubitrack_agent.services.scheduler``): looked at again every ``STATIC_POLL_S`` until the
        static inputs have their values (at most ``CURRENT_TIMEOUT_S``), and the producers' answers
        handled as they come, nothing waited for on the thread."""
        if self._stop.is_set() or generation != self._generation:
            return
        waiting = any(len(buffer) == 0 for buffer in statics)
        if waiting and time.monotonic() - asked_at <= CURRENT_TIMEOUT_S:
            again = (generation, local, remote, statics, asked_at)
            self._scheduler.later(STATIC_POLL_S, functools.partial(self._hand_current, *again))
            return
        for index, value in local:
            self._deliver_values(generation, index, [value])
        for index, key in remote:
            deliver = functools.partial(self._deliver_one, generation, index)
            self._ask_latest(key, deliver, CURRENT_TIMEOUT_S)

    def _deliver_one(self, generation: int, index: int, payload: bytes) -> None:
        self._deliver(generation, index, [payload])

    def _ask_static(
        self,
        wanted: list[tuple[str, Callable[[bytes], None], Callable[[], bool]]],
        hands: list[Callable[[], None]],
        attempt: int = 0,
    ) -> None:
        """:meth:`_fetch_static` in a container, on its scheduler's thread: each attempt of
        ``net.transport.FETCH_RETRY_DELAYS`` asks the producers of the inputs still without a
        value and is over at once (:meth:`_ask_latest`); the next is a timer."""
        for hand in hands:
            hand()
        if self._stop.is_set():
            return
        pending = [(key, take) for key, take, satisfied in wanted if not satisfied()]
        for key, take in pending:
            self._ask_latest(key, take, FETCH_TIMEOUT_S)
        if pending and attempt + 1 < len(FETCH_RETRY_DELAYS):
            again = functools.partial(self._ask_static, wanted, [], attempt + 1)
            self._scheduler.later(FETCH_RETRY_DELAYS[attempt + 1], again)

    def _ask_latest(self, key: str, deliver: Callable[[bytes], None], timeout: float) -> None:
        """Ask the queryables on ``key`` for their latest value without waiting: each answer
        is handed to ``deliver`` on the scheduler's thread."""
        call = self._scheduler.call

        def answer(reply: Any) -> None:
            if reply.ok is not None and not is_misaddressed(reply.ok):  # net.address
                call(functools.partial(deliver, reply.ok.payload.to_bytes()))

        self._session.get(key, on_zenoh_thread(self._guarded(answer)), timeout=timeout)

    def _fetch_static(
        self,
        wanted: list[tuple[str, Callable[[bytes], None], Callable[[], bool]]],
        latest: list[Callable[[], None]],
    ) -> None:
        """Hand the static inputs read in the container their producers' latest values, and
        fetch the others' (``net.transport.fetch_until_satisfied``)."""
        for hand in latest:
            hand()
        fetch_until_satisfied(self._session, wanted, self._stop)

    def _local(self, key: str) -> bool:
        """Whether another component of this worker's container produces ``key``."""
        return self._wires is not None and self._wires.producer(key) is not None

    def _subscribe(self, generation: int, index: int, binding: InputBinding) -> Any:
        """Input ``index``'s subscription: to the container's local wire if a component there
        produces its key (``ubitrack_agent.services.local_wires``), else to zenoh: a dynamic input's
        on a thread of its own (``net.transport.subscribe_in_bursts``), a static one's in a
        container on its scheduler's thread (a sample now and then: no thread for it)."""
        key = binding.key
        if self._local(key):
            handle = (self._on_value, self._on_value_run, generation, index)
            return self._wires.subscribe(key, functools.partial(self._handle, *handle))
        if binding.static and self._scheduler is not None:
            call, deliver = (
                self._scheduler.call,
                functools.partial(self._deliver_one, generation, index),
            )
            key_tag = tag(key)

            def take(sample: Any) -> None:
                if is_misaddressed(sample, key_tag):
                    self._gaps.refuse()
                    return
                call(functools.partial(deliver, sample.payload.to_bytes()))

            return self._session.declare_subscriber(key, on_zenoh_thread(self._guarded(take)))
        handle = (self._on_sample, self._on_run, generation, index)
        deliver = functools.partial(self._handle, *handle)
        return subscribe_in_bursts(self._session, key, deliver, gaps=self._gaps)

    def rebind(self) -> bool:
        """Move the inputs whose producer joined or left this worker's container onto the
        local wire or onto zenoh; nothing else changes (no sample in flight on another input is
        superseded, histories are kept). Whether any moved. O(inputs)."""
        moved = False
        with self._lock:
            if self._stop.is_set():
                return False
            for index, item in enumerate(self._inputs):
                if isinstance(item.subscriber, LocalSubscription) != self._local(item.binding.key):
                    item.subscriber.undeclare()
                    item.subscriber = self._subscribe(self._generation, index, item.binding)
                    moved = True
        return moved

    def _route_outputs(self, relations: dict[str, tuple[str, ...]]) -> None:
        """Publish each output port on its key and on the relation keys it serves, and the
        progress of a static estimate on the progress key of each static relation."""
        routes = {port: [key, *relations.get(port, ())] for port, key in self.spec.outputs.items()}
        progress_routes = {
            port: [self.keys.progress(relation) for relation in self._static_relations(keys)]
            for port, keys in relations.items()
        }
        answers = {key: port for port, keys in routes.items() for key in keys}
        wanted = {key for keys in (*routes.values(), *progress_routes.values()) for key in keys}
        self._put_outside()  # what is queued goes out on the publishers it was queued for
        for key in set(self._publishers) - wanted:
            self._publishers.pop(key).undeclare()
        for key in wanted - set(self._publishers):
            port = answers.get(key)
            at = None if port is None else (lambda t, port=port: self._ask(port, t))
            encoding = JSON if port is None else MSGPACK  # progress, or a measurement
            self._publishers[key] = LatestValuePublisher(
                self._session, key, at, self._counts, encoding, self._wake
            )
        self._watch_relations({key for keys in relations.values() for key in keys})
        self._routes = routes
        self._out = {
            port: _Route(keys[0], self._publishers_of(keys), self._publishers_of(keys[1:]))
            for port, keys in routes.items()
        }
        self._progress_routes = progress_routes

    def _watch_relations(self, relation_keys: set[str]) -> None:
        """Watch each dynamic relation key this worker puts on (make before break: one stream
        while another producer takes it over or gives it up, ``services.handover``)."""
        dynamic = {key for key in relation_keys if not self._static_relations((key,))}
        for key in set(self._hand_overs) - dynamic:
            self._hand_overs.pop(key).close()
        for key in dynamic - set(self._hand_overs):
            self._hand_overs[key] = Watch(self._session, key, self._counts, self._needed)

    def _static_relations(self, relation_keys: tuple[str, ...]) -> list[RelationId]:
        """The static relations among ``relation_keys`` (a key that is no relation key of
        this domain is only published on)."""
        relations = []
        for key in relation_keys:
            try:
                relations.append(self.keys.parse_relation(key))
            except ValueError:
                continue
        return [relation for relation in relations if relation.static]

    # -- control ------------------------------------------------------------------------------

    def _parse_control(self, payload: bytes) -> ControlCommand:
        """The command in ``payload``, checked against the running service; ``ValueError``
        (``SpecError``, ``MessageError``) naming what is wrong."""
        command = load_object(payload, MAX_CONTROL_BYTES)
        if not command or set(command) - CONTROL_FIELDS:
            raise SpecError(f"control: expected an object with some of {sorted(CONTROL_FIELDS)}")
        if "stop" in command:
            if set(command) != {"stop"} or command["stop"] is not True:
                raise SpecError('control.stop: expected {"stop": true} alone')
            return ControlCommand(stop=True)
        parsed = ControlCommand()
        if "parameters" in command:
            parameters = command["parameters"]
            if not isinstance(parameters, dict):
                raise SpecError("control.parameters: expected an object")
            service = check_parameters(parameters, self._service_class)
            parsed = replace(parsed, parameters=dict(parameters), service=service)
        if "inputs" in command:
            bindings = parse_bindings(command["inputs"], "control.inputs")
            check_bindings(bindings, self._service_class, self.spec.expansion, "control.inputs")
            parsed = replace(parsed, inputs=bindings)
        if "relations" in command:
            relations = parse_relations(command["relations"], "control.relations")
            check_relations(relations, self._service_class, "control.relations")
            parsed = replace(parsed, relations=relations)
        return parsed

    def _control_handler(self, key: str) -> Callable[[Any], None]:
        """The handler of control key ``key`` (on zenoh's thread): a command for the inbox, or
        one put on another key refused (``net.address``; counted ``misaddressed`` and
        summarised: a stop meant for another component would stop this one)."""
        key_tag = tag(key)

        def take(sample: Any) -> None:
            if is_misaddressed(sample, key_tag):
                self._counts["misaddressed"] += 1
                return
            self._inbox.put(("control", sample.payload.to_bytes()))

        return take

    def _apply_control(self, payload: bytes) -> None:
        """Apply a control command in full, or reject it (counted, logged) and keep running
        as before."""
        try:
            command = self._parse_control(payload)
        except ValueError as exc:
            self._count("rejected_commands", "rejected control command: %s", exc)
            return
        if command.stop:
            log.info("%s: stopped by control command", self.spec.instance)
            self.released = True
            self.stop()
            return
        if command.service is not None and command.parameters != self.spec.parameters:
            self.spec = replace(self.spec, parameters=command.parameters or {})
            self._service = command.service
            self._asynchronous = self._service.asynchronous()
            self._reports_progress = self._new_progress()
            self._accumulator = self._new_accumulator()
        if command.inputs is not None and command.inputs != self.spec.inputs:
            self.spec = replace(self.spec, inputs=command.inputs)
            self._bind(command.inputs)
        if command.relations is not None:
            self.spec = replace(self.spec, relations=command.relations)
            self._route_outputs(self.spec.relations)
        self._counts["rewired"] += 1
        log.info("%s: reconfigured", self.spec.instance)

    def _count(self, counter: str, message: str, *details: Any) -> None:
        """Count a rejection or an input consumed without an output; log it, rate-limited."""
        logs.count_problem(
            self._counts, counter, log, f"%s: {message}", self.spec.instance, *details
        )

    def _guarded(self, handler: Callable[..., None]) -> Callable[..., None]:
        """``handler`` made total (:func:`ubitrack_agent.net.logs.guarded`)."""
        return logs.guarded(handler, self._counts, log, self.spec.instance)

    # -- data path --------------------------------------------------------------------------

    def _on_sample(self, generation: int, index: int, payload: bytes) -> None:
        self._received += 1
        if generation != self._generation:
            self._counts["superseded"] += 1  # from a subscription a rewire replaced
            return
        item = self._inputs[index]
        try:
            decoded = decode(payload, item.expected, item.level)
        except MeasurementError as exc:
            self._count("rejected", "rejected sample on %s: %s", item.binding.key, exc)
            return
        self._take(item, decoded)

    def _on_value(self, generation: int, index: int, value: Measurement) -> None:
        """A value handed over by another component of the container
        (``ubitrack_agent.services.local_wires``): handled as a sample (:meth:`_on_sample`), with
        nothing to decode."""
        self._received += 1
        if generation != self._generation:
            self._counts["superseded"] += 1  # from a wire a rewire replaced
            return
        item = self._inputs[index]
        if not isinstance(value, item.expected):
            key = item.binding.key
            self._count("rejected", "rejected %s on %s", type(value).__name__, key)
            return
        self._take(item, value)

    def _take(self, item: _Input, decoded: Measurement) -> None:
        """A sample of ``item`` decoded (or handed over): admitted, buffered, triggering."""
        sample = self._admitted(item, decoded)
        if sample is None:
            return
        if self._asynchronous:
            self._push(item.binding.port, sample, item.binding.key)
            return
        if not item.buffer.add(sample):
            self._count_stale(item, sample)
            return
        t = sample.timestamp_ns
        if item.binding.static and self._held_for_static:
            self._release_held()
        if not item.binding.trigger:
            self._counts["buffered"] += 1
        elif item.binding.static:
            self._evaluate(t)  # a new static value: recompute at once
        elif (
            wait_s := 0.0 if len(self._dynamic) < 2 else self._wait_s(item, t)
        ) == 0.0 and not self._pending.deadlines:
            if not self._pending.finish(t):  # nothing to wait for: at once
                self._counts["stale_triggers"] += 1
            elif self._accumulator is not None:
                self._evaluate(t, item, sample)
            elif (values := self._values_at(t, item, sample)) is not None:
                self._compute(values, t)  # _evaluate's, a call fewer on every hop
        elif not self._pending.add(t, time.monotonic(), wait_s, extend=True):
            # Held until the other inputs catch up; an instant already computed is ignored.
            self._counts["stale_triggers"] += 1

    def _admitted(self, item: _Input, sample: Measurement) -> Measurement | None:
        """``sample`` of ``item`` on this host's clock (its input's clock offset added), its
        latency recorded, a fixed error's covariance marked static (``core.poses``); None if
        it is stamped ahead of the clock or the offset takes it out of range (counted)."""
        t = sample.timestamp_ns
        now = self._now_ns()
        if t - now > MAX_FUTURE_NS:  # core.timeline.ahead_of_clock, on the sensor's clock
            key = item.binding.key
            self._count("rejected_future", "rejected sample on %s stamped ahead: %d ns", key, t)
            return None
        if item.binding.clock_offset_ns:
            key = item.binding.key
            try:
                sample = sample.restamped(t + item.binding.clock_offset_ns)
            except MeasurementError as exc:
                self._count("rejected_clock", "rejected sample on %s, %d ns: %s", key, t, exc)
                return None
            t = sample.timestamp_ns
        if item.binding.fixed_error:  # the same in every result computed from it
            sample = with_static_error(sample)
        item.latency.append(now - t)
        if not item.seen:
            self._first_samples.setdefault(item.binding.key, time.time_ns())
            item.seen = True
        return sample

    def _count_stale(self, item: _Input, sample: Measurement) -> None:
        """Count ``sample``, which its input's buffer refused: older than all it holds."""
        key, t = item.binding.key, sample.timestamp_ns
        self._count("dropped_stale", "dropped sample on %s older than its buffer: %d", key, t)

    def _takes_runs(self, generation: int, index: int) -> bool:
        """Whether samples of input ``index`` waiting together may be handled as one run
        (:meth:`_on_run`): it is the one dynamic input and it triggers, and nothing holds a
        sample back (no asynchronous service, time expansion, progress report or pending
        trigger), so :meth:`_on_sample` would compute each at once."""
        if generation != self._generation:
            return False
        item = self._inputs[index]
        binding = item.binding
        return (
            binding.trigger
            and not binding.static
            and len(self._dynamic) == 1
            and not self._asynchronous
            and self._accumulator is None
            and not self._reports_progress
            and not self._pending.deadlines
        )

    def _on_run(self, generation: int, index: int, payloads: list[bytes]) -> None:
        """Samples of one input taken from the inbox together (:meth:`_takes_runs`), each
        handled as :meth:`_on_sample` would, decoded together (``core.codec.decode_run``) and
        computed together where the service vectorises (:meth:`_run`)."""
        self._received += len(payloads)
        self._counts["in_runs"] += len(payloads)
        item = self._inputs[index]
        decoded = []
        for value in decode_run(payloads, item.expected, item.level):
            if isinstance(value, MeasurementError):
                self._count("rejected", "rejected sample on %s: %s", item.binding.key, value)
            else:
                decoded.append(value)
        self._run(item, decoded)

    def _on_value_run(self, generation: int, index: int, values: list[Measurement]) -> None:
        """Values handed over together by another component of the container (a run it
        computed, ``ubitrack_agent.services.local_wires``), handled as :meth:`_on_value` would,
        computed together where the service vectorises (:meth:`_run`)."""
        self._received += len(values)
        self._counts["in_runs"] += len(values)
        item = self._inputs[index]
        taken = []
        for value in values:
            if isinstance(value, item.expected):
                taken.append(value)
            else:
                self._count("rejected", "rejected %s on %s", type(value).__name__, item.binding.key)
        self._run(item, taken)

    def _run(self, item: _Input, values: list[Measurement]) -> None:
        """A run of ``item``'s samples, each admitted and buffered as :meth:`_take` would, then
        computed together where the service vectorises (:meth:`Service.compute_run`): under
        load, a numpy call per run instead of one per sample (``docs/performance.md``, "Data
        path")."""
        instants: list[tuple[dict[str, Any], int]] = []
        for value in values:
            sample = self._admitted(item, value)
            if sample is None:
                continue
            if not item.buffer.add(sample):
                self._count_stale(item, sample)
                continue
            t = sample.timestamp_ns
            if not self._pending.finish(t):
                self._counts["stale_triggers"] += 1
            elif (inputs := self._values_at(t, item, sample)) is not None:
                instants.append((inputs, t))
        if self._computes_runs and len(instants) > 1:
            try:
                outputs = self._service.compute_run(*zip(*instants, strict=True))
            except (TooFewCorrespondences, ValueError, MeasurementError, ArithmeticError):
                pass  # computed one by one below, each failure counted
            else:
                for computed, (_, t) in zip(outputs, instants, strict=True):
                    self._publish_computed(computed, t)
                return
        for inputs, t in instants:
            self._compute(inputs, t)

    def _wait_s(self, trigger: _Input, timestamp_ns: int) -> float:
        """How long a trigger may wait for the other live dynamic inputs
        (ubitrack_agent.services.triggers): briefly for the missing samples of its own instant only
        once enough of them are in to compute (the correspondences a space expansion needs, else
        all), so a frame whose samples trickle in on a loaded machine is not computed from too
        few."""
        dynamic = self._dynamic
        if len(dynamic) < 2:
            return 0.0  # the trigger is the one dynamic input: nothing to wait for
        others = [b for b in dynamic if b is not trigger.buffer]
        cap_ns = int(self.spec.wait_ms * 1e6)
        present = sum(b.has_sample_at(timestamp_ns) for b in dynamic)
        needed = (
            self._service.min_correspondences() if self.spec.expansion == "space" else len(dynamic)
        )
        same_instant = trigger.buffer if present >= needed else None
        every = (
            self.spec.expansion != "space"
        )  # each input needed (ubitrack_agent.services.triggers)
        return wait_for(others, timestamp_ns, self.spec.tolerance_ns, cap_ns, same_instant, every)

    def _caught_up(self, timestamp_ns: int) -> bool:
        every = self.spec.expansion != "space"
        return not lagging(self._dynamic, timestamp_ns, self.spec.tolerance_ns, every)

    def _process_due_triggers(self) -> None:
        for timestamp_ns in self._pending.due(time.monotonic(), self._caught_up):
            self._evaluate(timestamp_ns)

    def _evaluate(
        self, t: int, trigger: _Input | None = None, sample: Measurement | None = None
    ) -> None:
        """Evaluate every input at ``t`` and compute (see :mod:`ubitrack_agent.services.triggers`);
        the value of the ``trigger`` input, if given, is its ``sample`` stamped ``t`` (just
        added)."""
        values = self._values_at(t, trigger, sample)
        if values is None:
            return
        if self._accumulator is None:
            self._compute(values, t)
        elif not self._accumulator.add(values):
            self._counts["not_distinct"] += 1
        elif not self._accumulator.ready():
            self._counts["accumulating"] += 1
        else:
            self._compute(self._accumulator.expanded(values), t)

    def _values_at(
        self, t: int, trigger: _Input | None, sample: Measurement | None
    ) -> dict[str, Any] | None:
        """The service's inputs at ``t`` by port (see :meth:`_evaluate`); None if one has no
        value then (counted ``dropped``)."""
        values: dict[str, Any] = {}
        space, tolerance_ns = self._space, self._tolerance_ns
        for item in self._inputs:
            port = item.binding.port
            value = sample if item is trigger else item.buffer.value_at(t, tolerance_ns)
            if space and port in self._service_class.CORRESPONDENCE:
                values.setdefault(port, []).append(value)
            elif value is None:
                if item.binding.static and not len(item.buffer):
                    self._hold_for_static(t, trigger, sample)
                else:
                    self._counts["dropped"] += 1
                return None
            else:
                values[port] = value
        return values

    def _hold_for_static(self, t: int, trigger: _Input | None, sample: Measurement | None) -> None:
        """Keep a trigger that came before a static input's first value (issue [seamless]:
        a fusion's first A.R.T. samples were dropped while it waited for the static ART->WT);
        the oldest beyond ``MAX_HELD_FOR_STATIC`` is dropped. O(1)."""
        held = self._held_for_static
        if held and held[-1][0] >= t:
            self._counts["dropped"] += 1  # an instant held already, or older than the newest
            return
        held.append((t, trigger, sample))
        self._counts["held_for_static"] += 1
        if len(held) > MAX_HELD_FOR_STATIC:
            held.popleft()
            self._counts["dropped"] += 1

    def _release_held(self) -> None:
        """Compute the held triggers, oldest first, once every static input has a value (those
        still short of one are held again)."""
        held, self._held_for_static = self._held_for_static, deque()
        for t, trigger, sample in held:
            self._evaluate(t, trigger, sample)

    def _push(self, port: str, sample: Measurement, source: str) -> None:
        """An asynchronous service's update by one sample of ``source`` (its input's key),
        published at once."""
        try:
            pushed: Pushed = self._service.push(port, sample, source)
        except (ValueError, MeasurementError, ArithmeticError) as exc:
            self._count("failed", "update failed: %s", exc)
            return
        if pushed.outputs:
            self._publish(pushed.outputs, sample.timestamp_ns)
        else:
            self._counts[pushed.reason] += 1

    def _compute(self, values: dict[str, Any], timestamp_ns: int) -> None:
        try:
            outputs = self._service.compute(values, timestamp_ns)
        except TooFewCorrespondences:
            self._counts["too_few_correspondences"] += 1  # expected: summarised
            return
        except (ValueError, MeasurementError, ArithmeticError) as exc:
            self._count("failed", "computation failed: %s", exc)
            return
        if not outputs:
            self._counts["no_output"] += 1
        self._publish(outputs, timestamp_ns)

    def _publish_computed(self, outputs: dict[str, Any], timestamp_ns: int) -> None:
        if not outputs:
            self._counts["no_output"] += 1
        self._publish(outputs, timestamp_ns)

    def _publish(self, outputs: dict[str, Any], timestamp_ns: int) -> None:
        """Hand each output to its readers in the container (delivered once this worker's lock
        is free: ``ubitrack_agent.services.local_wires``) and queue its puts for readers outside the
        process, put after the hand-over (:meth:`_put_outside`), so the container's flow does not
        wait for zenoh; under ``_lock``. A value handed over is checked finite here and encoded when
        put; one only zenoh carries is encoded here, where a result's numbers are checked.
        O(outputs x routes)."""
        wires = self._wires
        for port, value in outputs.items():
            route = self._out.get(port)
            readers = None if wires is None or route is None else wires.readers.get(route.key)
            if readers:
                if not finite(value):
                    self._count("failed", "result of %s holds NaN or infinity", port)
                    continue
                wires.hand_over(route.key, readers, value, self._handed)
                self._handed_over += 1
                self._published += 1
                # What zenoh must carry besides: the relation keys, and the data key while a
                # subscriber outside this process listens (zenoh's matching status, told to
                # the publisher: net.transport.LatestValuePublisher); else the value is
                # remembered, to be sent when one appears (_send_unsent).
                if route.publishers[0].matching:
                    self._outgoing.append((route.publishers, value, None))
                else:
                    self._not_sent += 1
                    self._unsent.add(route.key)
                    if route.relations:
                        self._outgoing.append((route.relations, value, None))
                continue
            try:
                payload = encode(value)  # where a result's numbers are checked
            except MeasurementError as exc:
                self._count("failed", "result not published: %s", exc)
                continue
            if route is not None:
                if wires is not None:  # a reader bound later in the container starts here
                    wires.keep(route.key, value)
                self._outgoing.append((route.publishers, value, payload))
            self._published += 1
        if self._reports_progress or self._batch_progress is not None:
            self._publish_progress(outputs, timestamp_ns)

    def _publishers_of(self, routes: list[str]) -> tuple[LatestValuePublisher, ...]:
        return tuple(self._publishers[key] for key in routes)

    def _put_outside(self) -> None:
        """Put what :meth:`_publish` queued, oldest first; called after the hand-over in the
        container (``ubitrack_agent.services.local_wires``), with ``_lock`` free or held (never
        taken here). One thread at a time puts (``_put_lock``), each taking whatever is queued then,
        so the samples of one key leave in the order they were published even where two threads
        publish it. O(puts queued)."""
        if self._outgoing:
            with self._put_lock:
                self._put_outside_held()

    def _put_outside_held(self) -> None:
        """:meth:`_put_outside`'s puts, ``_put_lock`` held."""
        outgoing, hand_overs = self._outgoing, self._hand_overs
        while outgoing:
            publishers, value, payload = outgoing.popleft()
            if payload is None:
                payload = encode(value)
            for publisher in publishers:
                hand_over = hand_overs.get(publisher.key)
                if hand_over is None:
                    publisher.put(payload)
                    continue
                put = functools.partial(hand_over.put, publisher.put, payload, value)
                if hand_over.rules.admit(value, put):
                    put()

    def _wake(self) -> None:
        """Wake the worker thread (a subscriber appeared: :meth:`_send_unsent`)."""
        self._inbox.put(("wake",))

    def _send_unsent(self) -> None:
        """Put the latest value of each output key read in the container that zenoh has not
        carried, once a subscriber outside listens (a reader in another process started
        later: it gets the current value, as from a publisher that always put it)."""
        for key in list(self._unsent):
            publisher = self._publishers.get(key)
            value = self._wires.latest(key) if self._wires is not None else None
            if publisher is None or value is None:
                self._unsent.discard(key)
            elif publisher.matching:
                self._unsent.discard(key)
                self._outgoing.append(((publisher,), value, None))

    def _publish_progress(self, outputs: dict[str, Any], timestamp_ns: int) -> None:
        """The progress of each static estimate (``ubitrack_agent.net.progress``), also when
        there is no estimate to publish (still initialising, or the relation moves)."""
        reports = self._service.progress()
        if self._batch_progress is not None and self._accumulator is not None:
            samples = len(self._accumulator)
            for port, value in outputs.items():
                tracker = self._batch_progress.setdefault(port, BatchProgress())
                reports[port] = tracker.update(value, samples, timestamp_ns)
        for port, progress in reports.items():
            progress = replace(progress, instance=self.spec.instance)
            self.progress[port] = progress
            payload = progress.to_json().encode()
            routes = self._progress_routes.get(port, ())
            if routes:
                self._outgoing.append((self._publishers_of(routes), payload, payload))

    # -- values at a given time (net.time_queries) --------------------------------------------

    def _ask(self, port: str, timestamp_ns: int) -> bytes:
        """Runs on an answering thread (``net.transport.ANSWERS``): output ``port``'s value at
        a time, encoded, or a typed error (``ValueError``, ``LookupError``, ``TimeoutError``:
        ``net.time_queries``); an unexpected fault is logged and counted (``internal_errors``)
        and answered as :class:`NoDataError`."""
        if not self._lock.acquire(timeout=ANSWER_TIMEOUT_S):
            raise TimeoutError(f"no answer within {ANSWER_TIMEOUT_S} s (the worker is busy)")
        try:
            payload = encode(self._value_at(port, timestamp_ns))
        except (ValueError, LookupError, TimeoutError):
            self._counts["time_queries_refused"] += 1
            raise
        except Exception:
            where = self.spec.instance
            logs.count_problem(
                self._counts, "internal_errors", log, "%s: internal error", where, exc_info=True
            )
            raise NoDataError("the worker could not answer") from None
        else:
            self._counts["time_queries"] += 1
        finally:
            self._lock.release()
        return payload

    def _value_at(self, port: str, t: int) -> Measurement:
        """Output ``port`` at ``t``: an asynchronous service's own answer (its filter's
        prediction); otherwise computed from every input at ``t``, each interpolated within
        its samples or, after them, asked of its producer in turn (a chain of such queries
        ends at a filter that predicts, or at a measured edge, which refuses). A time
        expansion's result is not a function of time and is not answered."""
        if self._asynchronous:
            return self._service.value_at(port, t)
        if self.spec.expansion == "time":
            raise ExtrapolationError("a time-expanded estimate has no value at a given time")
        space = self.spec.expansion == "space"
        values: dict[str, Any] = {}
        no_model: list[NoMotionModel] = []
        for item in self._inputs:
            correspondence = space and item.binding.port in self._service_class.CORRESPONDENCE
            try:
                value: Measurement | None = self._input_at(item, t)
            except (ExtrapolationError, NoDataError, TimeoutError, MeasurementError) as exc:
                if not correspondence:
                    raise
                value = None  # a space expansion uses the rows it has
                if isinstance(exc, NoMotionModel):
                    no_model.append(exc)
            if correspondence:
                values.setdefault(item.binding.port, []).append(value)
            else:
                values[item.binding.port] = value
        if no_model and all(
            v is None for p in self._service_class.CORRESPONDENCE for v in values.get(p, ())
        ):
            raise no_model[0]  # none of the rows can be predicted
        try:
            outputs = self._service.compute(values, t)
        except ExtrapolationError:
            raise
        except (ValueError, ArithmeticError) as exc:
            raise NoDataError(f"no value at {t}: {exc}") from None
        if port not in outputs:
            raise NoDataError(f"no value of {port} at {t}")
        return outputs[port]

    def _input_at(self, item: _Input, t: int) -> Measurement:
        buffer = item.buffer
        newest = buffer.newest_time()
        if newest is None:
            raise NoDataError(f"no sample of {item.binding.key} yet")
        if buffer.static or t <= newest:
            return buffer.lookup(t)
        if time.monotonic() < self._no_model.get(item.binding.key, 0.0):
            raise NoMotionModel(f"{item.binding.key} has no motion model")
        upstream_t = t - item.binding.clock_offset_ns  # the time on the producer's clock
        if not 0 <= upstream_t <= MAX_TIMESTAMP_NS:
            raise ExtrapolationError(f"{upstream_t} is no time on {item.binding.key}'s clock")
        try:
            payload = fetch_at(self._session, item.binding.key, upstream_t, UPSTREAM_TIMEOUT_S)
        except (NoMotionModel, NoDataError) as exc:  # nothing to predict, or nobody answers
            self._no_model[item.binding.key] = time.monotonic() + NO_MODEL_S
            raise NoMotionModel(f"{item.binding.key}: {exc}") from None
        value = decode(payload, expected=item.expected)
        if value.timestamp_ns != upstream_t:
            raise ExtrapolationError(f"{item.binding.key} answered for another time")
        return value.restamped(t)

    # -- status and life cycle ----------------------------------------------------------------

    def status(self) -> dict[str, Any]:
        return {
            "instance": self.spec.instance,
            "service": self.spec.service,
            "pid": os.getpid(),
            "incarnation": self.incarnation,
            "counters": dict(self.counters),
            **({"pool": dict(self.pool_counters)} if self.pool_counters is not None else {}),
            "progress": {port: asdict(progress) for port, progress in self.progress.items()},
            "latency_ms": self._latencies(),
            "handling_us": round(self._handling_s * 1e6, 1),
            "spec": self.spec.as_dict(),
            "stamps": {
                **self.stamps,
                "first_sample_ns": dict(self._first_samples),
                "first_published_ns": {
                    key: publisher.first_put_ns
                    for key, publisher in list(self._publishers.items())
                    if publisher.first_put_ns is not None
                },
            },
            **({"container": self.container} if self.container is not None else {}),
            "holds": sorted(k for k, watch in list(self._hand_overs.items()) if watch.rules.holds),
        }

    def _latencies(self) -> dict[str, float]:
        """The median latency (ms) of each dynamic input's latest samples (see ``_latency``)."""
        keys = {item.binding.key for item in self._inputs if not item.binding.static}
        return {
            key: round(statistics.median(list(values)) / 1e6, 3)
            for key, values in list(self._latency.items())
            if key in keys and values
        }

    def _reply_status(self, query: Any) -> None:
        with query:
            status = json.dumps(self.status())
            query.reply(self.keys.status(self.spec.instance), status, encoding=JSON)

    def stop(self) -> None:
        self._stopping = True
        self._stop.set()
        self._inbox.put(("wake",))  # the worker thread ends now, not after its idle wait

    def _deliver(self, generation: int, index: int, payloads: list[bytes]) -> None:
        """Handle samples of input ``index`` of binding ``generation`` taken together
        (:meth:`_handle`), on the thread that took them (an input's, or one fetching a
        current value)."""
        self._handle(self._on_sample, self._on_run, generation, index, payloads)

    def _deliver_values(self, generation: int, index: int, values: list[Measurement]) -> None:
        """Handle values handed over on input ``index`` of binding ``generation`` by another
        component of the container (``ubitrack_agent.services.local_wires``), on that component's
        thread, as :meth:`_deliver` handles samples."""
        self._handle(self._on_value, self._on_value_run, generation, index, values)

    def _handle(
        self,
        each: Callable[[int, int, Any], None],
        run: Callable[[int, int, list], None],
        generation: int,
        index: int,
        items: list,
    ) -> None:
        """Handle ``items`` (samples, or values handed over) of input ``index`` under
        ``_lock``: at least :data:`RUN_MIN` as one run where it may (:meth:`_takes_runs`),
        else one by one, each followed by the triggers due; then wake the worker thread if a
        trigger is held that is due before it would wake, and, the lock released, hand the
        outputs to the container's readers (``ubitrack_agent.services.local_wires``) and put those
        for readers outside. Total: an unexpected exception is counted (``internal_errors``) and
        logged, and the next item handled. Every :data:`TIME_EVERY`-th call is timed
        (``handling_us``). Nothing after :meth:`stop`. O(items + outputs)."""
        with self._lock:
            self._deliveries += 1
            timed = self._deliveries % TIME_EVERY == 1  # the first, then one in TIME_EVERY
            start = time.perf_counter() if timed else 0.0
            if len(items) >= RUN_MIN and self._takes_runs(generation, index):
                try:
                    if not self._stopping:
                        run(generation, index, items)
                except Exception:
                    self._internal_error()
            else:
                for item in items:
                    if self._stopping:
                        break
                    try:
                        each(generation, index, item)
                        if self._pending.deadlines:
                            self._process_due_triggers()
                    except Exception:
                        self._internal_error()
            if timed:
                each_s = (time.perf_counter() - start) / len(items)
                self._handling_s += HANDLING_GAIN * (each_s - self._handling_s)
            if self._pending.deadlines:
                self._wake_for_held()
            handed = self._handed
            if handed:
                self._handed = []
        if handed or self._outgoing:
            self._hand_on(handed)

    def _hand_on(self, handed: Handed) -> None:
        """Deliver ``handed`` to the readers in the container, then put what is queued for
        readers outside (:meth:`_put_outside`); ``_lock`` free. Total."""
        try:
            if len(handed) == 1 and len(handed[0][0]) == 1:  # a hop of a chain: one call fewer
                handed[0][0][0].deliver([handed[0][1]])
            elif handed:
                deliver(handed)
            if self._outgoing:
                self._put_outside()
        except Exception:
            self._internal_error()

    def _internal_error(self) -> None:
        """Count and log the exception being handled (``internal_errors``)."""
        logs.count_problem(
            self._counts,
            "internal_errors",
            log,
            "%s: internal error",
            self.spec.instance,
            exc_info=True,
        )

    def _wake_for_held(self) -> None:
        """Wake the worker thread if a trigger is held that is due before it would wake;
        under ``_lock``."""
        deadline = self._pending.next_deadline()
        if deadline is not None and deadline < self._wakes_at:
            self._wakes_at = deadline
            self._inbox.put(("wake",))

    def step(self, longest_s: float = IDLE_S) -> None:
        """The worker thread's turn: wait at most ``longest_s``, or until the next trigger
        held is due, for control commands, status queries (or a wake-up); then do what is
        due (:meth:`_turn`). The inputs' samples are handled on their own threads
        (:meth:`_deliver`)."""
        with self._lock:
            deadline = self._pending.next_deadline()
            now = time.monotonic()
            timeout = longest_s if deadline is None else min(longest_s, max(0.0, deadline - now))
            self._wakes_at = now + timeout
        self._turn(self._inbox.take(timeout))

    def turn(self) -> float | None:
        """A turn given by the container's scheduler (``ubitrack_agent.services.scheduler``), woken
        by an item in the inbox or its deadline: do what is due (:meth:`_turn`) without waiting;
        when the next turn is due (a trigger held, the next summary), None once stopped."""
        self._turn(self._inbox.take_waiting())
        with self._lock:
            if self._stop.is_set():
                return None
            deadline = self._pending.next_deadline()
            due = self._summary_due if deadline is None else min(deadline, self._summary_due)
            self._wakes_at = due
        return due

    def _turn(self, items: list[tuple[Any, ...]]) -> None:
        """Answer the status queries and apply the control commands among ``items`` in order,
        then compute the triggers due, send the values a new subscriber outside waits for and
        summarise; never raises (:meth:`_guarded`)."""
        for item in items:
            if item[0] == "status":
                self._guarded(self._reply_status)(item[1])
        with self._lock:
            if self._stop.is_set():  # closed (a turn asked for before): nothing more
                return
            self._wakes_at = -math.inf  # awake: an input's thread need not wake it
            for item in items:
                if self._stop.is_set():
                    return
                if item[0] == "control":
                    self._guarded(self._apply_control)(item[1])
            if self._pending.deadlines:
                self._guarded(self._process_due_triggers)()
            if self._unsent:
                self._guarded(self._send_unsent)()
            self._summarise(time.monotonic())
            handed = self._handed
            if handed:
                self._handed = []
        self._hand_on(handed)

    def _summarise(self, now: float) -> None:
        """Every ``SUMMARY_S``, one warning for each condition counted meanwhile that may come
        many times a second (instants with too few correspondences, which are expected, and
        messages refused as put on another key), instead of one per instant."""
        if now < self._summary_due:
            return
        counted = self._counts["too_few_correspondences"]
        if counted > self._summarised:
            log.warning(
                "%s: %d instant(s) with too few correspondences in the last %.0f s "
                "(a feature hidden; %d in all)",
                self.spec.instance,
                counted - self._summarised,
                SUMMARY_S,
                counted,
            )
        refused = self._gaps.misaddressed + self._counts["misaddressed"]
        if refused > self._refused_summarised:
            log.warning(
                "%s: %d message(s) refused as put on another key in the last %.0f s "
                "(zenoh delivered them on this one: net.address; %d in all)",
                self.spec.instance,
                refused - self._refused_summarised,
                SUMMARY_S,
                refused,
            )
        self._summarised, self._summary_due = counted, now + SUMMARY_S
        self._refused_summarised = refused

    def run(self) -> None:
        """Take commands and compute held triggers (:meth:`step`) until :meth:`stop`; then
        undeclare everything (:meth:`close`)."""
        try:
            while not self._stop.is_set():
                self.step()
        finally:
            self.close()

    @property
    def stopped(self) -> bool:
        """Whether :meth:`stop` was called (a stop command, or whoever runs it)."""
        return self._stop.is_set()

    def close(self) -> None:
        """Stop, and undeclare everything; a container's component ends here (it has no
        thread of its own: ``ubitrack_agent.services.container``)."""
        self._stopping = True
        self._stop.set()
        with self._lock:  # no thread is handling a sample or a turn; none will after this
            pass
        if self._scheduler is not None:
            self._scheduler.forget(self)
        self._token.undeclare()
        if self._wires is not None:
            self._wires.produce(self.spec.instance, ())
            self._wires.reads(self.spec.instance, ())
        for item in self._inputs:
            item.subscriber.undeclare()
        for control in self._controls:
            control.undeclare()
        self._status.undeclare()
        with self._put_lock:  # a thread still putting what it queued finishes first
            self._put_outside_held()
            for publisher in self._publishers.values():
                publisher.undeclare()
            for hand_over in self._hand_overs.values():
                hand_over.close()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m ubitrack_agent.services.worker",
        description="Run one pattern instance from a component specification (JSON).",
    )
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--spec", help="the specification as JSON text")
    source.add_argument("--spec-file", help="a file holding the specification")
    parser.add_argument(
        "--pool-id",
        help="member of the host manager's warm pool: idle, fully imported, it runs the "
        "specification sent to <root>/pool/<ID> (or --spec first) and returns to the pool when "
        "released, or the group sent there as a container until that ends; when its standard "
        "input closes (the host manager is gone) it exits unless "
        "its worker token is up, and then once released",
    )
    logs.add_log_level_argument(parser)
    config.add_arguments(parser)
    return parser


class Pool:
    """Pool membership of a worker process: idles fully imported until a specification comes
    on ``<root>/pool/<id>``, runs it, and, when the agent releases it (a stop command),
    returns to the pool instead of exiting, so the process's imports are paid once. Given a
    group instead, the process runs it as a container (:mod:`ubitrack_agent.services.container`).

    The process lives on after its host manager (``parent``, :mod:`ubitrack_agent.services.parent`)
    only while it serves: idle, it leaves the pool when its host manager is gone, and it exits at
    once if that happens while it starts (an assigned worker keeps running: a restarted agent adopts
    it). SIGTERM or SIGINT ends it. A specification that is not a bounded JSON object
    (``net.json_messages``), is malformed, or names no registered service wired as it
    declares (``ubitrack_agent.services.spec.check_spec``) is rejected, logged rate-limited and
    counted in :attr:`counters` (``rejected_specs``; shown in the status of the instances it runs);
    the member keeps waiting.
    """

    def __init__(self, session: Any, keys: KeySpace, pool_id: str, parent: Parent) -> None:
        self.session, self.keys, self.pool_id, self.parent = session, keys, pool_id, parent
        self.counters: Counter[str] = Counter(rejected_specs=0, internal_errors=0)
        self._inbox: queue.SimpleQueue[bytes | None] = queue.SimpleQueue()
        parent.when_gone(lambda: self._inbox.put(None))
        lookup("relay")  # imports every registered service and its maths
        # And the container's module, which this process becomes given a group: it imports this
        # module again (run as ``__main__``, it is not ``ubitrack_agent.services.worker`` yet),
        # 70-240 ms at a load of 6 that a restored container's applications waited for.
        importlib.import_module("ubitrack_agent.services.container")

    def wait(self) -> ComponentSpec | GroupSpec | None:
        """The next specification (or group, for a container), or None when the process
        should end."""
        if not self.parent.idle():
            return None
        receive = logs.guarded(
            lambda sample: self._inbox.put(sample.payload.to_bytes()),
            self.counters,
            log,
            f"pool worker {self.pool_id}",
        )
        subscriber = self.session.declare_subscriber(self.keys.pool(self.pool_id), receive)
        token = self.session.liveliness().declare_token(self.keys.pool(self.pool_id))
        on_termination(lambda: self._inbox.put(None))
        try:
            while (payload := self._inbox.get()) is not None:
                spec = self._read_spec(payload)
                if spec is not None:
                    return spec if self.parent.start() else None
            return None
        finally:
            token.undeclare()
            subscriber.undeclare()

    def _read_spec(self, payload: bytes) -> ComponentSpec | GroupSpec | None:
        """The specification or group in ``payload`` checked in full, or None (rejected,
        counted)."""
        try:
            spec = parse_assignment(payload)
            for component in spec.components if isinstance(spec, GroupSpec) else (spec,):
                check_spec(component)
        except SpecError as exc:
            logs.count_problem(
                self.counters,
                "rejected_specs",
                log,
                "pool worker %s: rejected specification: %s",
                self.pool_id,
                exc,
            )
            return None
        return spec


def run_worker(
    session: Any, keys: KeySpace, spec: ComponentSpec, clock: Clock, pool: Pool | None = None
) -> bool:
    """Run one component until stopped; True if the agent released it (it may be reused).
    The objects of the process's start-up are left out of the garbage collector's work first
    (``services.heap``)."""
    settle_collector()
    counters, parent = (None, None) if pool is None else (pool.counters, pool.parent)
    worker = Worker(spec, session, keys, counters, clock, parent)
    on_termination(worker.stop)
    log.info("%s: running %s", spec.instance, spec.service)
    worker.run()
    return worker.released


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logs.configure(args.log_level)
    if args.spec is None and args.spec_file is None and args.pool_id is None:
        print("worker: give --spec, --spec-file or --pool-id", file=sys.stderr)
        return 2
    # Watched first, before every service is imported: that takes seconds on a loaded machine.
    parent = Parent() if args.pool_id else None
    try:
        spec = None
        if args.spec_file is not None:
            with open(args.spec_file, encoding="utf-8") as file:
                args.spec = file.read()
        if args.spec is not None:
            spec = parse_spec(args.spec)
            check_spec(spec)
        settings = config.from_arguments(args, role="member")
    except (OSError, SpecError, config.ConfigError) as exc:
        print(f"worker: {exc}", file=sys.stderr)
        return 2
    from ubitrack_agent.net.session import open_session

    keys = KeySpace(settings.key_prefix)
    with open_session(settings) as session:
        pool = Pool(session, keys, args.pool_id, parent) if parent is not None else None
        while True:
            if spec is None:
                spec = pool.wait() if pool is not None else None
                if spec is None:
                    return 0
            if isinstance(spec, GroupSpec):  # the member becomes a container; it ends with it
                # Imported here, not at the top: ubitrack_agent.services.container builds on this
                # module (a pool member imported it while it warmed up: Pool).
                from ubitrack_agent.services.container import run_container

                run_container(session, keys, spec, Clock.of(settings), parent)
                return 0
            released = run_worker(session, keys, spec, Clock.of(settings), pool)
            if not (released and pool is not None):
                return 0
            spec = None  # back to the pool


if __name__ == "__main__":
    sys.exit(main())
