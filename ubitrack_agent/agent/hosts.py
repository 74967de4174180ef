"""The agent's side of the host managers (``ubitrack_agent.services.host``): where each instance
runs, and starting and stopping workers over zenoh only (``docs/protocol.md``).

* Host managers are known from their liveliness tokens ``<root>/host/<name>`` (with history).
  What each says of itself (labels, capacity, CPU load: :class:`HostInfo`) is asked with a
  status request when it appears and every ``INFO_REFRESH_S`` after, without waiting for the
  reply (a host manager that does not answer holds up nothing); until it answers it counts as
  a host without labels. An instance it runs that has no placement (a worker adopted from an
  earlier agent, or the old process of a move whose new host vanished) gets it from there.
* A start goes to the host manager :mod:`.placement` chose, as a ``get`` on
  ``<root>/host/<name>/request`` with a timeout: the components of one container
  (``agent.placement.group_containers``) in one ``start_group`` request (split only where it
  would pass the protocol's message size); the reply names each one's run, remembered with
  the host and the container as the instance's :class:`Placement`. With no host manager
  alive, or no answer, or a refusal, the start does not happen and the runtime asks again on
  a later pass (a refused or unanswered instance after ``START_RETRY_S``; a host manager that
  did not answer is left alone for as long). A host manager starts nothing twice: it answers
  a repeated start of a running instance with the same run.
* A stop goes to the instance's host manager; an instance without one (adopted from an earlier
  agent, or whose host manager vanished or does not answer) is stopped by putting the stop
  command on its control key. A clean stop of the agent sends every stop at once and waits
  ``REQUEST_TIMEOUT_S`` for all the replies together (:meth:`Hosts.stop_all`), so its exit
  does not grow with the components.
* Host managers report instances that ended without being asked on
  ``<root>/host/<name>/exited``; a report matching the instance's placement (same host, same
  run) means it must be started again. Only those reports end a placed instance: its worker
  token vanishing is not enough (the token of an instance started again may replace the old
  one before the old one's removal arrives). A report that the instance's container died and
  was restored keeps its placement: the instance is listed in :attr:`Hosts.restored`, with the
  new process's pid, for the agent to send it its current wiring. When a host manager
  vanishes, its instances lose their placement; those not alive must be started again.
* A report can be missing: an instance that ended by a stop command its host manager did not
  send (released: a stop meant for another that zenoh delivered to it, ``net.address``) is
  reported on its container's ``left`` key, which a partition may lose. So when a placed
  instance's token vanishes (:meth:`Hosts.await_exit`) its host manager is asked for its status
  at once, and a reply asked for after that which does not list the instance under its run
  ends it too (counted ``exits_unreported``). O(awaited instances) a reply.

Zenoh callbacks only queue; everything else runs on the agent's thread (:meth:`Hosts.reap`).
"""

from __future__ import annotations

import logging
import queue
import time
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from typing import Any

import zenoh

from ubitrack_agent.agent.problems import Problems
from ubitrack_agent.net.address import is_misaddressed
from ubitrack_agent.net.clock import ClockEstimate
from ubitrack_agent.net.host_protocol import (
    MAX_MESSAGE_BYTES,
    STOP_COMMAND,
    Exited,
    HostInfo,
    ProtocolError,
    Request,
    StartedGroup,
    StartGroup,
    Status,
    Stop,
    encode_request,
)
from ubitrack_agent.net.keys import KeyRejection, KeySpace
from ubitrack_agent.net.spec import ComponentSpec, GroupSpec
from ubitrack_agent.net.transport import put_command

log = logging.getLogger("ubitrack.agent")

REQUEST_TIMEOUT_S = 2.0
"""Longest wait for a host manager's reply (it answers in milliseconds)."""
INFO_REFRESH_S = 5.0
"""How often each host manager's information (its CPU load changes) is asked again."""
START_RETRY_S = 1.0
"""After a refused or unanswered start, wait this long before asking again for the instance;
a host manager that did not answer is not asked anything for as long."""
PUT = "SampleKind.PUT"


@dataclass(frozen=True)
class Placement:
    """Where an instance runs: the host manager that started it, the run it named, and the
    process's pid (which the worker's token incarnation carries) and container (None: a
    process of its own); neither compared."""

    host: str
    run: str
    pid: int = field(default=0, compare=False)
    container: str | None = field(default=None, compare=False)


class Hosts:
    """The host managers on ``session`` and the instances placed on them."""

    def __init__(self, session: Any, keys: KeySpace, problems: Problems) -> None:
        self._session = session
        self._keys = keys
        self._problems = problems
        self.live: set[str] = set()
        self.info: dict[str, HostInfo] = {}
        """What each live host manager said of itself (its latest status reply)."""
        self._clocks: dict[str, tuple[ClockEstimate, float]] = {}
        """Each host's latest clock estimate and when it came (``time.monotonic``), kept when
        its host manager vanishes: the machine's clock, its sensors and workers may well
        still run."""
        self._info_due: dict[str, float] = {}
        self.placements: dict[str, Placement] = {}
        self._lost: list[str] = []
        self.restored: dict[str, int] = {}
        """Instances whose container died and was restored by its host manager, with the new
        process's pid: the agent takes them (and sends each its current wiring)."""
        self._retry_at: dict[str, float] = {}
        self._silent_until: dict[str, float] = {}
        self._waiting = False
        self._events: queue.SimpleQueue[tuple[str, str, Any]] = queue.SimpleQueue()
        self._awaited: dict[str, float] = {}
        """Placed instances whose token vanished, by when (:meth:`await_exit`)."""
        self._watch = session.liveliness().declare_subscriber(
            keys.all_hosts(),
            lambda s: self._events.put((str(s.kind), str(s.key_expr), b"")),
            history=True,
        )
        self._exits = session.declare_subscriber(keys.all_host_exits(), self._on_exit_report)
        self._containers: dict[str, str] = {}
        """The container each container process runs, by pid (from the containers' tokens)."""
        self._container_watch = session.liveliness().declare_subscriber(
            keys.all_containers(),
            lambda s: self._events.put(("container", str(s.key_expr), str(s.kind).encode())),
            history=True,
        )

    def reports_exit_of(self, instance: str) -> bool:
        """Whether a live host manager runs ``instance`` (and reports when it ends)."""
        placement = self.placements.get(instance)
        return placement is not None and placement.host in self.live

    # -- requests ---------------------------------------------------------------------------

    def available(self) -> dict[str, HostInfo]:
        """The host managers to place instances on: live, answering, by name, with what they
        said of themselves."""
        if not self.live and not self._waiting:
            log.info("no host manager alive yet: starting waits for one")
            self._waiting = True
        return {host: self.info.get(host, HostInfo(host)) for host in self._answering()}

    def start_group(self, group: GroupSpec, host: str) -> list[str]:
        """Have ``host``'s manager run ``group``'s components in its container; the instances
        it started (ask again later for the others). An instance running elsewhere is started
        there too: the agent keeps the new process and stops the other (a move, make before
        break). O(components) and one request per :data:`MAX_MESSAGE_BYTES` of them."""
        now = time.monotonic()
        specs = [spec for spec in group.components if now >= self._retry_at.get(spec.instance, 0)]
        started: list[str] = []
        for part in _parts(specs):
            if host not in self._answering():
                break
            try:
                reply = StartedGroup.parse(
                    self._request(host, StartGroup(GroupSpec(group.container, part)))
                )
            except ProtocolError as exc:
                for spec in part:
                    self._retry_at[spec.instance] = time.monotonic() + START_RETRY_S
                self._problems.report(
                    "refused_starts",
                    "%d components: host %s did not start them in %s: %s",
                    len(part),
                    host,
                    group.container,
                    exc,
                )
                continue
            for one in reply.started:
                self._retry_at.pop(one.instance, None)
                self.placements[one.instance] = Placement(host, one.run, one.pid, reply.container)
                started.append(one.instance)
            log.info(
                "%d components started on host %s in container %s",
                len(reply.started),
                host,
                reply.container,
            )
        return started

    def stop(self, instance: str) -> bool:
        """Stop ``instance`` through its host manager, else with the stop command; True if a
        host manager took the stop (it then owns the process until it has ended)."""
        self._retry_at.pop(instance, None)
        placement = self.placements.pop(instance, None)
        if placement is not None and placement.host in self._answering():
            try:
                self._request(placement.host, Stop(instance))
                return True
            except ProtocolError as exc:
                self._problems.report("failed_stops", "%s: host did not stop it: %s", instance, exc)
        put_command(self._session, self._keys.control(instance), STOP_COMMAND)
        return False

    def stop_all(self, instances: Iterable[str]) -> int:
        """Stop ``instances`` as :meth:`stop` does, every request sent at once and their
        replies awaited together, ``REQUEST_TIMEOUT_S`` in all (not each: a clean stop of the
        agent ends in bounded time); an instance whose host manager did not take its stop in
        time, or that has none, gets the stop command. How many host managers took.
        O(instances)."""
        answering = set(self._answering())
        replies: queue.SimpleQueue[tuple[str, bool]] = queue.SimpleQueue()
        asked: set[str] = set()
        for instance in instances:
            self._retry_at.pop(instance, None)
            placement = self.placements.pop(instance, None)
            if placement is not None and placement.host in answering:
                try:
                    self._session.get(
                        self._keys.host_request(placement.host),
                        payload=encode_request(Stop(instance)),
                        timeout=REQUEST_TIMEOUT_S,
                        handler=lambda reply, instance=instance: replies.put(
                            (instance, reply.ok is not None)
                        ),
                    )
                    asked.add(instance)
                    continue
                except zenoh.ZError as exc:
                    log.warning("%s: could not ask its host manager to stop it: %s", instance, exc)
            put_command(self._session, self._keys.control(instance), STOP_COMMAND)
        taken, deadline = 0, time.monotonic() + REQUEST_TIMEOUT_S
        while asked and (left := deadline - time.monotonic()) > 0:
            try:
                instance, ok = replies.get(timeout=left)
            except queue.Empty:
                break
            if instance in asked:
                asked.discard(instance)
                taken += ok
                if not ok:
                    put_command(self._session, self._keys.control(instance), STOP_COMMAND)
        for instance in sorted(asked):  # no reply in time
            self._problems.report("failed_stops", "%s: host did not answer its stop", instance)
            put_command(self._session, self._keys.control(instance), STOP_COMMAND)
        return taken

    def _answering(self) -> list[str]:
        """Live host managers by name, less those that did not answer lately."""
        now = time.monotonic()
        return sorted(h for h in self.live if self._silent_until.get(h, 0.0) <= now)

    def _request(self, host: str, request: Request) -> bytes:
        """The payload of ``host``'s successful reply; :class:`ProtocolError` for a refusal, no
        answer or a zenoh error (then ``host`` is left alone for ``START_RETRY_S``). An error
        reply that is not a host manager's refusal is zenoh's own (``Timeout`` when the host
        manager's token is up but its process does not answer, as across a cut link): no
        answer."""
        try:
            replies = list(
                self._session.get(
                    self._keys.host_request(host),
                    payload=encode_request(request),
                    timeout=REQUEST_TIMEOUT_S,
                )
            )
        except zenoh.ZError as exc:
            replies, reason = [], f"request failed: {exc}"
        else:
            reason = f"no answer within {REQUEST_TIMEOUT_S} s"
            if any(r.ok is not None and is_misaddressed(r.ok) for r in replies):
                replies, reason = [], "a reply put on another key (net.address)"
        if replies and replies[0].ok is None:
            error = replies[0].err.payload.to_bytes()
            try:
                refusal = ProtocolError.parse(error)
            except ProtocolError:
                replies, reason = [], f"no answer ({error[:80].decode(errors='replace')})"
            else:
                raise refusal
        if not replies:
            self._silent_until[host] = time.monotonic() + START_RETRY_S
            raise ProtocolError("internal_error", reason)
        return replies[0].ok.payload.to_bytes()

    def _ask_info(self) -> None:
        """Ask every live host manager whose information is due for its status; the replies
        arrive as events."""
        now = time.monotonic()
        for host in sorted(self.live):
            if now < self._info_due.get(host, 0.0):
                continue
            self._info_due[host] = now + INFO_REFRESH_S
            try:
                self._session.get(
                    self._keys.host_request(host),
                    payload=encode_request(Status()),
                    timeout=REQUEST_TIMEOUT_S,
                    handler=lambda reply, host=host, at=now: self._events.put(
                        ("info", host, (_reply_bytes(reply), at))
                    ),
                )
            except zenoh.ZError as exc:
                log.warning("could not ask host manager %s for its status: %s", host, exc)

    # -- events -----------------------------------------------------------------------------

    def _on_exit_report(self, sample: Any) -> None:
        """On zenoh's thread: queue a host manager's exit report, unless its attachment names
        another key (``net.address``: zenoh delivered it here), which is counted."""
        if is_misaddressed(sample):
            self._problems.report(
                "misaddressed", "refused an exit report put on another key than %s", sample.key_expr
            )
            return
        self._events.put(("exited", str(sample.key_expr), sample.payload.to_bytes()))

    def reap(self, alive: set[str]) -> list[str]:
        """Apply host tokens, exit reports and status replies, and ask for information that
        is due; the instances to start again (``alive``: the instances whose worker token is
        up)."""
        ended: list[str] = []
        while not self._events.empty():
            kind, key, payload = self._events.get_nowait()
            if kind == "info":
                ended += self._on_info(key, *payload)
                continue
            if kind == "container":
                self._on_container(key, payload.decode() == PUT)
                continue
            token = self._keys.parse_token("host_exited" if kind == "exited" else "host", key)
            if isinstance(token, KeyRejection):
                self._problems.report(
                    token.counter, "ignored %s key %r: %s", token.kind, token.key, token.reason
                )
            elif kind == "exited":
                ended += self._on_exited(token.name, payload)
            else:
                self._on_host(token.name, kind == PUT, alive)
        for instance in [i for i in self._awaited if i in alive or i not in self.placements]:
            del self._awaited[instance]  # back (its process reconnected), or ended otherwise
        self._ask_info()
        return ended

    def await_exit(self, instance: str) -> None:
        """``instance``'s worker token vanished while a live host manager runs it: ask that host
        manager for its status now, and end the instance if a reply asked for from now on
        does not list it (its exit report lost; module docstring)."""
        placement = self.placements.get(instance)
        if placement is None or placement.host not in self.live:
            return
        self._awaited.setdefault(instance, time.monotonic())
        self._info_due[placement.host] = 0.0

    def _on_info(self, host: str, payload: bytes | None, asked_at: float) -> list[str]:
        """Take a host manager's status reply (None: an error reply) to a request sent at
        ``asked_at``; the awaited instances it shows ended (:meth:`await_exit`)."""
        if host not in self.live or payload is None:
            return []
        try:
            info = HostInfo.parse(payload)
            if info.name != host:
                raise ProtocolError("malformed_request", f"name: {info.name!r}, not {host!r}")
        except ProtocolError as exc:
            self._problems.report(
                "rejected_host_reports", "ignored status of host manager %s: %s", host, exc
            )
            return []
        if self.info.get(host, HostInfo(host)).labels != info.labels:
            log.info("host manager %s has labels %s", host, ", ".join(sorted(info.labels)))
        self.info[host] = info
        for instance, (run, pid, container) in sorted(info.runs.items()):
            if instance not in self.placements:  # adopted, or a move failed half-way
                self.placements[instance] = Placement(host, run, pid, container)
                log.info("%s: runs on host %s (run %s)", instance, host, run)
        if info.clock is not None:
            self._clocks[host] = (info.clock, time.monotonic())
        return self._unreported_exits(info, asked_at)

    def _unreported_exits(self, info: HostInfo, asked_at: float) -> list[str]:
        """The awaited instances placed on ``info``'s host that its status, asked for after
        their token vanished, does not list under their run: ended without a report."""
        ended = []
        for instance, since in list(self._awaited.items()):
            placement = self.placements.get(instance)
            if placement is None or placement.host != info.name:
                continue
            if asked_at < since:
                continue  # a reply to a request older than the vanishing
            del self._awaited[instance]
            running = info.runs.get(instance)
            if running is not None and running[0] == placement.run:
                continue  # it runs: its token will be back (or its exit reported)
            del self.placements[instance]
            self._problems.report(
                "exits_unreported",
                "%s: ended on host %s without an exit report (its status no longer lists it)",
                instance,
                info.name,
            )
            ended.append(instance)
        return ended

    def _on_container(self, key: str, appeared: bool) -> None:
        """A container's token: which container its process runs."""
        token = self._keys.parse_token("container", key)
        if isinstance(token, KeyRejection):
            self._problems.report(
                token.counter, "ignored %s key %r: %s", token.kind, token.key, token.reason
            )
            return
        pid = token.incarnation.partition(".")[0]
        if appeared:
            self._containers[pid] = token.name
        elif self._containers.get(pid) == token.name:
            del self._containers[pid]

    def container_of(self, instance: str, incarnations: Iterable[str]) -> str | None:
        """The container ``instance`` runs in: its placement's, else (a component adopted
        from a container whose host manager is gone) that of a process among its
        ``incarnations`` (``<pid>.<nonce>``) whose container token is up. O(incarnations)."""
        placement = self.placements.get(instance)
        if placement is not None and placement.container is not None:
            return placement.container
        for incarnation in incarnations:
            container = self._containers.get(incarnation.partition(".")[0])
            if container is not None:
                return container
        return None

    def clocks(self) -> dict[str, ClockEstimate]:
        """Each host's latest clock estimate, aged since it came (its uncertainty grows with the
        drift the clocks may have had: ``ClockEstimate.aged``)."""
        now = time.monotonic()
        return {host: clock.aged(now - at) for host, (clock, at) in self._clocks.items()}

    def _on_host(self, host: str, appeared: bool, alive: set[str]) -> None:
        if appeared:
            self.live.add(host)
            self._waiting = False
            log.info("host manager %s is alive", host)
            return
        self.live.discard(host)
        self.info.pop(host, None)
        self._info_due.pop(host, None)
        log.warning("host manager %s vanished", host)
        lost = sorted(i for i, p in self.placements.items() if p.host == host)
        for instance in lost:
            del self.placements[instance]
        if lost:  # those still alive run elsewhere (a move's old process): ask where now
            self._info_due.clear()
        self._lost += [instance for instance in lost if instance not in alive]

    def take_lost(self) -> list[str]:
        """The instances whose host manager vanished while their token was down, since last
        asked: a process that was the host manager's client may come back through the hub
        (the agent waits a moment before it starts them again)."""
        lost, self._lost = self._lost, []
        return lost

    def _on_exited(self, host: str, payload: bytes) -> list[str]:
        try:
            exited = Exited.parse(payload)
        except ProtocolError as exc:
            self._problems.report(
                "rejected_host_reports", "ignored exit report of %s: %s", host, exc
            )
            return []
        placement = self.placements.get(exited.instance)
        if placement != Placement(host, exited.run):
            return []  # an earlier run, or not ours
        if exited.reason == "restored":
            log.warning("%s: its container on host %s was restored", exited.instance, host)
            self.placements[exited.instance] = replace(placement, pid=exited.pid)
            self.restored[exited.instance] = exited.pid
            return []
        del self.placements[exited.instance]
        log.warning("%s: worker ended on host %s (%s)", exited.instance, host, exited.reason)
        return [exited.instance]

    def close(self) -> None:
        self._watch.undeclare()
        self._exits.undeclare()
        self._container_watch.undeclare()


def _parts(specs: list[ComponentSpec]) -> list[tuple[ComponentSpec, ...]]:
    """``specs`` in runs whose start_group request stays well below the protocol's message
    size (half of :data:`MAX_MESSAGE_BYTES`: the request wraps them)."""
    parts: list[tuple[ComponentSpec, ...]] = []
    part: list[ComponentSpec] = []
    size = 0
    for spec in specs:
        length = len(spec.to_json())
        if part and size + length > MAX_MESSAGE_BYTES // 2:
            parts.append(tuple(part))
            part, size = [], 0
        part.append(spec)
        size += length
    if part:
        parts.append(tuple(part))
    return parts


def _reply_bytes(reply: Any) -> bytes | None:
    """A reply's payload; None for an error reply."""
    return None if reply.ok is None else reply.ok.payload.to_bytes()
