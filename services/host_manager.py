"""The host manager's zenoh side: its token, its request queryable and its exit reports.

One host manager runs per machine (:mod:`ubitrack_agent.services.host` starts it) and owns that
machine's worker processes through a :class:`ubitrack_agent.services.supervisor.Supervisor`. It
declares

* the liveliness token ``<root>/host/<name>`` once it serves requests;
* the queryable ``<root>/host/<name>/request``: start, start_group, stop and status requests
  (:mod:`ubitrack_agent.net.host_protocol`); a start's specification (each of a group's) is
  checked for form and against the registered service and its parameters
  (``ubitrack_agent.services.spec.check_spec``) before anything runs, so only registered services
  run;
* ``<root>/host/<name>/exited``: an :class:`~ubitrack_agent.net.host_protocol.Exited` for every
  instance that ended without being asked (its process exited, even before declaring its
  worker token, or a stop command from elsewhere released it), so the agent starts it again;
  and every component of a container that died and was restored (the agent rewires it).

It watches the tokens of containers (``<root>/container/<name>/<incarnation>``: a container
takes commands once its token is up) and their reports of components that left
(``<root>/left/<name>``), for the containers its supervisor runs. It also reads the control
commands on ``<root>/control/<instance>`` that rewire its components in place (inputs,
relations, parameters: the agent sends them to the component directly), and keeps each
component's specification current with them, so a container that dies is restored running
what its components ran, not what they were started with (:func:`rewired`).

A container that a host manager of its name left running when it died (killed: its containers
outlive it) is adopted as it starts, or when its token appears later: found by its token,
confirmed in ``/proc`` (a worker process of this machine, host name and key space; no host
manager its parent), asked for its components' specifications, and run from then on as if
started here, so it is restored when it dies (:mod:`ubitrack_agent.services.adoption`; asking
blocks the handling thread up to ``ASK_TIMEOUT_S``, once per orphan).

While it runs it estimates its host's clock offset to the active agent's
(:mod:`ubitrack_agent.services.clock_sync`), shown in its status as ``clock``.

One started by an agent (``ubitrack_agent.services.host --started-by-agent``) outlives that agent
(:meth:`HostManager.orphan`): its containers, the pool and the route of its client worker
processes (``docs/services.md``, "Links") stay, and the agent's successor adopts it rather
than starting another. It watches the active agent's tokens (``<root>/agents/*/active``) and
ends once it has run no component and seen no active agent for ``ORPHAN_END_S``, or, running
components, once it has seen no active agent for ``ABANDONED_END_S`` (they end with it).

Zenoh callbacks and the request thread only queue; one thread handles every event, request
and process. Handling is total: a malformed request gets an error reply of its type, is
counted and logged (rate-limited, :func:`ubitrack_agent.net.logs.rate_limited`), and never
stops the host manager.
"""

from __future__ import annotations

import json
import logging
import os
import queue
import threading
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import zenoh

from ubitrack_agent.net import logs
from ubitrack_agent.net.address import is_misaddressed, reply_addressed, tag
from ubitrack_agent.net.clock import Clock
from ubitrack_agent.net.encodings import JSON
from ubitrack_agent.net.host_protocol import (
    HostInfo,
    ProtocolError,
    Request,
    Start,
    StartGroup,
    Status,
    Stop,
    parse_request,
)
from ubitrack_agent.net.json_messages import MessageError, load_object
from ubitrack_agent.net.keys import KeyRejection, KeySpace
from ubitrack_agent.net.spec import MAX_SPEC_BYTES, ComponentSpec, SpecError, parse_spec
from ubitrack_agent.services.adoption import ASK_TIMEOUT_S, LocalWorker, ask_orphan, orphan_worker
from ubitrack_agent.services.clock_sync import ClockSync
from ubitrack_agent.services.host import ABANDONED_END_S, ORPHAN_END_S
from ubitrack_agent.services.registry import lookup
from ubitrack_agent.services.spec import check_spec
from ubitrack_agent.services.supervisor import Supervisor
from ubitrack_agent.services.worker import CONTROL_FIELDS

log = logging.getLogger("ubitrack.host")

LOOP_S = 0.05
"""Longest wait for an event before processes are reaped and the pool topped up."""
MAX_PENDING_REQUESTS = 64
"""Requests queued for the handling thread at most; beyond, the request thread stops taking
them from zenoh (whose own queue then fills), so a flood cannot grow memory without bound."""
PUT = "SampleKind.PUT"


class HostManager:
    """Serves host requests on an open zenoh ``session`` until :meth:`stop`."""

    def __init__(
        self,
        session: Any,
        keys: KeySpace,
        info: HostInfo,
        worker_flags: Sequence[str],
        pool_size: int,
        clock: Clock | None = None,
    ) -> None:
        self.counters: Counter[str] = Counter()
        self.supervisor = Supervisor(session, keys, worker_flags, pool_size, self.counters)
        # The first pool member imports beside this process's own imports (two processes for
        # the start-up's imports, not one after the other): a container asked for at once
        # goes to it (``Supervisor._take_starting``), not to a cold process spawned later.
        self.supervisor.fill_pool()
        lookup("relay")  # import every registered service now, not on the first request
        self.info = info
        self.name = name = info.name
        self.keys = keys
        self.clock_sync = ClockSync(session, keys, clock or Clock(), self.counters)
        """This host's clock (the process's, ``Settings.clock_offset_ms`` applied) against
        the agent's."""
        self._events: queue.SimpleQueue[tuple[str, Any]] = queue.SimpleQueue()
        self._stop = threading.Event()
        self._orphaned = threading.Event()
        self._active_agents: set[str] = set()
        self._unneeded_since: float | None = None
        self._agentless_since: float | None = None
        self._request_slots = threading.Semaphore(MAX_PENDING_REQUESTS)
        liveliness = session.liveliness()
        self._pool_watch = liveliness.declare_subscriber(
            keys.all_pools(), self._queue("pool", "pool token"), history=True
        )
        self._container_watch = liveliness.declare_subscriber(
            keys.all_containers(), self._queue("container", "container token"), history=True
        )
        self._left = session.declare_subscriber(
            keys.all_container_left(), self._queue("left", "container report")
        )
        self._control_prefix = f"{keys.root}/control/"
        self._controls = session.declare_subscriber(
            f"{self._control_prefix}*", self._queue("control", "control command")
        )
        self._agent_watch = liveliness.declare_subscriber(
            keys.all_active_agents(), self._queue("agent", "agent token"), history=True
        )
        self._exits = session.declare_publisher(keys.host_exited(name), encoding=JSON)
        self._exits_tag = tag(keys.host_exited(name))
        self._session = session
        self._prefix, _, self._domain = keys.root.rpartition("/")
        self._orphans_asked: set[str] = set()
        """Incarnations of containers asked whether they are orphans (once each)."""
        self._adopt_running_orphans(liveliness)
        self._requests = session.declare_queryable(keys.host_request(name))
        self._request_thread = threading.Thread(target=self._receive_requests, daemon=True)
        self._request_thread.start()
        self._token = liveliness.declare_token(keys.host(name))

    def _adopt_running_orphans(self, liveliness: Any) -> None:
        """Adopt the containers a host manager of this name left running here when it died
        (:mod:`ubitrack_agent.services.adoption`), before serving: the first status the agent
        asks names their components. One found later (its token came back late) is adopted
        when its token appears (:meth:`_on_container_token`)."""
        try:
            replies = list(liveliness.get(self.keys.all_containers(), timeout=ASK_TIMEOUT_S))
        except zenoh.ZError as exc:
            log.warning("could not look for orphaned containers: %s", exc)
            return
        for reply in replies:
            if reply.ok is not None:
                self._on_container_token(PUT, str(reply.ok.key_expr))

    def _orphan(self, name: str, incarnation: str) -> LocalWorker | None:
        """The process of container ``name`` (``incarnation``) if it is an orphan of this
        host's not asked yet (``/proc``, not the network, says so), else None."""
        pid = incarnation.partition(".")[0]
        if incarnation in self._orphans_asked or not pid.isdigit():
            return None
        if self.supervisor.knows_container(name, int(pid)):
            return None
        worker = orphan_worker(int(pid), self.name, self._prefix, self._domain)
        if worker is None:
            return None
        self._orphans_asked.add(incarnation)
        return worker

    def _adopt(self, name: str, incarnation: str, worker: LocalWorker) -> None:
        """Ask orphan container ``name`` what it runs (blocks up to ``ASK_TIMEOUT_S``) and
        adopt it (on the handling thread, or before it runs)."""
        try:
            orphan = ask_orphan(self._session, self.keys, name, incarnation, worker)
        except SpecError as exc:
            self._count_problem("rejected_orphans", "orphaned container not adopted: %s", exc)
            return
        self.supervisor.adopt(orphan)

    def _queue(self, kind: str, what: str) -> Any:
        """A zenoh callback queueing its sample for the handling thread as ``kind``: a token's
        change and key, or (``left``, ``control``) a message's key and payload; faults
        counted."""

        def queue_sample(sample: Any) -> None:
            if kind in ("left", "control"):
                if is_misaddressed(sample):  # zenoh delivered it on another key: net.address
                    self.counters["misaddressed"] += 1
                    return
                self._events.put((kind, (str(sample.key_expr), sample.payload.to_bytes())))
            else:
                self._events.put((kind, (str(sample.kind), str(sample.key_expr))))

        return logs.guarded(queue_sample, self.counters, log, what)

    def _ask_awaited_tokens(self) -> None:
        """Ask the router for the tokens the supervisor has awaited too long
        (:meth:`Supervisor.awaited_tokens`); the replies come back as ``<kind>_found``
        events, without blocking this thread."""
        for kind, selector in self.supervisor.awaited_tokens(time.monotonic()):

            def found(reply: Any, kind: str = kind) -> None:
                if reply.ok is not None:
                    self._events.put((f"{kind}_found", str(reply.ok.key_expr)))

            guarded = logs.guarded(found, self.counters, log, f"{kind} token asked for")
            try:
                self._session.liveliness().get(selector, guarded, timeout=ASK_TIMEOUT_S)
            except zenoh.ZError as exc:
                self._count_problem("failed_token_queries", "could not ask for tokens: %s", exc)

    def _receive_requests(self) -> None:
        for query in self._requests:
            while not self._request_slots.acquire(timeout=LOOP_S):
                if self._stop.is_set():
                    return
            self._events.put(("request", query))

    # -- events -------------------------------------------------------------------------------

    def run(self) -> None:
        """Handle requests and pool tokens, reap and refill, until :meth:`stop`."""
        handle = logs.guarded(self._handle, self.counters, log, "host event")
        self.clock_sync.start()
        try:
            while not self._stop.is_set():
                try:
                    kind, event = self._events.get(timeout=LOOP_S)
                    handle(kind, event)
                    while not self._events.empty():
                        handle(*self._events.get_nowait())
                except queue.Empty:
                    pass
                for exited in self.supervisor.reap():
                    self._exits.put(exited.to_json(), attachment=self._exits_tag)
                    self.counters["exits_reported"] += 1
                self._ask_awaited_tokens()
                self.supervisor.fill_pool()
                self._end_if_unneeded()
        finally:
            self._close()

    def stop(self) -> None:
        """End :meth:`run`, terminating every worker."""
        self._stop.set()

    def orphan(self) -> None:
        """The agent that started this host manager is gone (died, stopped, or stood by): go
        on serving for its successor, which adopts it; end as :meth:`_end_if_unneeded` says
        (module docstring)."""
        if not self._orphaned.is_set():
            log.warning(
                "the agent that started this host manager is gone: serving on for its successor"
            )
            self._orphaned.set()

    def _end_if_unneeded(self) -> None:
        """Stop an orphaned host manager that has been unneeded for ``ORPHAN_END_S``, or has
        seen no active agent for ``ABANDONED_END_S`` (its components stopped with it)."""
        if not self._orphaned.is_set() or self._active_agents:
            self._unneeded_since = self._agentless_since = None
            return
        now = time.monotonic()
        if self._agentless_since is None:
            self._agentless_since = now
        if self.supervisor.assigned or self.supervisor.containers:
            self._unneeded_since = None
        elif self._unneeded_since is None:
            self._unneeded_since = now
        if now - self._agentless_since > ABANDONED_END_S:
            waited = now - self._agentless_since
            self._end(
                "ended_abandoned", f"no active agent for {waited:.0f} s: ending with its components"
            )
        elif self._unneeded_since is not None and now - self._unneeded_since > ORPHAN_END_S:
            waited = now - self._unneeded_since
            self._end(
                "ended_unneeded", f"no component and no active agent for {waited:.0f} s: ending"
            )

    def _end(self, counter: str, message: str) -> None:
        """Stop, counted in ``counter`` and logged with ``message``."""
        log.warning(message)
        self.counters[counter] += 1
        self.stop()

    def _handle(self, kind: str, event: Any) -> None:
        if kind == "request":
            self._answer(event)
            return
        if kind == "container":
            self._on_container_token(*event)
            return
        if kind == "left":
            self._on_left(*event)
            return
        if kind == "agent":
            self._on_agent_token(*event)
            return
        if kind == "control":
            self._on_control(*event)
            return
        if kind == "container_found":
            self._on_container_token(PUT, event, found=True)
            return
        change, key = (PUT, event) if kind == "pool_found" else event
        try:
            pool_id = self.keys.parse_pool(key)
        except ValueError as exc:
            self._count_problem("rejected_pool_keys", "ignored malformed pool key: %s", exc)
            return
        if kind == "pool_found":
            self.supervisor.on_pool_token_found(pool_id)
            return
        exited = self.supervisor.on_pool_token(pool_id, change == PUT)
        if exited is not None:
            self._exits.put(exited.to_json(), attachment=self._exits_tag)
            self.counters["exits_reported"] += 1

    def _on_container_token(self, change: str, key: str, found: bool = False) -> None:
        """A container's token changed, or was ``found`` by asking (:meth:`_ask_awaited_tokens`:
        it only ends a wait, adopting nothing)."""
        token = self.keys.parse_token("container", key)
        if isinstance(token, KeyRejection):
            reason = ValueError(f"{token.key!r}: {token.reason}")
            self._count_problem("rejected_container_keys", "ignored container key: %s", reason)
            return
        name, incarnation = token.name, token.incarnation
        if found:
            self.supervisor.on_container_token_found(name, incarnation)
            return
        self.supervisor.on_container_token(name, incarnation, change == PUT)
        if change == PUT and (worker := self._orphan(name, incarnation)) is not None:
            self._adopt(name, incarnation, worker)

    def _on_agent_token(self, change: str, key: str) -> None:
        try:
            agent = self.keys.parse_active_agent(key)
        except ValueError as exc:
            self._count_problem("rejected_agent_keys", "ignored agent key: %s", exc)
            return
        if change == PUT:
            self._active_agents.add(agent)
        else:
            self._active_agents.discard(agent)

    def _on_control(self, key: str, payload: bytes) -> None:
        """A control command to a component this host manager runs: its specification follows
        a rewire (one the component refuses is ignored here too, counted)."""
        spec = self.supervisor.spec_of(key.removeprefix(self._control_prefix))
        if spec is None:
            return  # not a component of ours (another host's, or a container's own key)
        try:
            current = rewired(spec, payload)
        except (MessageError, SpecError) as exc:
            reason = ValueError(f"{spec.instance}: {exc}")
            self._count_problem("ignored_rewires", "ignored rewire: %s", reason)
            return
        if current != spec:
            self.supervisor.rewire(current)
            self.counters["rewires_followed"] += 1

    def _on_left(self, key: str, payload: bytes) -> None:
        try:
            name = self.keys.parse_container_left(key)
            exits = self.supervisor.on_left(name, payload)
        except (ValueError, ProtocolError) as exc:
            self._count_problem("rejected_container_reports", "ignored container report: %s", exc)
            return
        for exited in exits:
            self._exits.put(exited.to_json(), attachment=self._exits_tag)
            self.counters["exits_reported"] += 1

    # -- requests -----------------------------------------------------------------------------

    def _answer(self, query: Any) -> None:
        """Reply to one request: never raises (a fault is an ``internal_error`` reply)."""
        self._request_slots.release()
        with query:
            self.counters["requests"] += 1
            try:
                payload = None if query.payload is None else query.payload.to_bytes()
                reply = self._serve(parse_request(payload))
            except ProtocolError as refusal:
                self._refuse(query, refusal)
                return
            except Exception as exc:  # a fault of ours must not end the host manager
                fault = ProtocolError("internal_error", type(exc).__name__)
                self._refuse(query, fault, with_traceback=True)
                return
            try:
                reply_addressed(query, self.keys.host_request(self.name), reply, JSON)
            except zenoh.ZError as exc:
                log.warning("could not reply: %s", exc)

    def _refuse(self, query: Any, refusal: ProtocolError, with_traceback: bool = False) -> None:
        self._count_problem(f"{refusal.error}s", "refused request: %s", refusal, with_traceback)
        try:
            query.reply_err(refusal.to_json())
        except zenoh.ZError as exc:
            log.warning("could not reply: %s", exc)

    def _count_problem(
        self, counter: str, message: str, detail: Exception, with_traceback: bool = False
    ) -> None:
        """Count a problem; log it (rate-limited), with the traceback being handled if asked."""
        logs.count_problem(self.counters, counter, log, message, detail, exc_info=with_traceback)

    def _serve(self, request: Request) -> str:
        """The JSON reply to a well-formed request; :class:`ProtocolError` if refused."""
        match request:
            case Start(spec=spec):
                try:
                    check_spec(spec)
                except SpecError as exc:
                    raise ProtocolError("refused_spec", str(exc)) from None
                self._check_capacity((spec.instance,))
                return self.supervisor.start(spec).to_json()
            case StartGroup(group=group):
                for index, spec in enumerate(group.components):
                    try:
                        check_spec(spec)
                    except SpecError as exc:
                        raise ProtocolError("refused_spec", f"components[{index}]: {exc}") from None
                self._check_capacity(tuple(spec.instance for spec in group.components))
                return self.supervisor.start_group(group).to_json()
            case Stop(instance=instance):
                return json.dumps({"instance": instance, "process": self.supervisor.stop(instance)})
            case Status():
                return json.dumps(self.status())

    def _check_capacity(self, instances: tuple[str, ...]) -> None:
        """:class:`ProtocolError` if starting ``instances`` would exceed the capacity (a start
        of a running instance replaces it: that is no more)."""
        running = self.supervisor.assigned
        new = sum(instance not in running for instance in instances)
        if new and len(running) + new > self.info.capacity:
            raise ProtocolError(
                "over_capacity",
                f"runs {len(running)} components, {new} more would pass its capacity "
                f"{self.info.capacity}",
            )

    def status(self) -> dict[str, Any]:
        """Name, labels, capacity and CPU load (:class:`HostInfo`), pid, whether its agent is
        gone (``orphaned``), pool, instances, clock offset and counters (JSON-ready)."""
        cpu_load = os.getloadavg()[0] / (os.cpu_count() or 1)
        return {
            **replace(self.info, cpu_load=round(cpu_load, 3)).as_dict(),
            "pid": os.getpid(),
            "orphaned": self._orphaned.is_set(),
            **self.supervisor.status(),
            "clock": self.clock_sync.status(),
            "counters": dict(self.counters),
        }

    # -- end ----------------------------------------------------------------------------------

    def _close(self) -> None:
        self.clock_sync.stop()
        self._token.undeclare()
        self._requests.undeclare()
        self._request_thread.join(timeout=1.0)
        self._pool_watch.undeclare()
        self._container_watch.undeclare()
        self._left.undeclare()
        self._controls.undeclare()
        self._agent_watch.undeclare()
        while not self._events.empty():  # unanswered requests end now, not at their timeout
            kind, event = self._events.get_nowait()
            if kind == "request":
                event.drop()
        self.supervisor.terminate_all()
        self._exits.undeclare()


def rewired(spec: ComponentSpec, payload: bytes) -> ComponentSpec:
    """``spec`` as the control command ``payload`` leaves it: its inputs, relations and
    parameters replaced by those the command names (``ubitrack_agent.services.worker``'s in-place
    rewire; a stop changes nothing), checked as a start's specification (``check_spec``).
    :class:`MessageError` or :class:`SpecError` if the command is malformed or refused.
    O(size of the specification)."""
    command = load_object(payload, MAX_SPEC_BYTES)
    if not command or set(command) - CONTROL_FIELDS:
        raise SpecError(f"control: expected an object with some of {sorted(CONTROL_FIELDS)}")
    changes = {name: value for name, value in command.items() if name != "stop"}
    if not changes:
        return spec
    current = parse_spec({**spec.as_dict(), **changes})
    check_spec(current)
    return current
