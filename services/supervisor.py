"""The worker processes of one machine: a warm pool, the instances running, those stopping.

The host manager (:mod:`ubitrack_agent.services.host_manager`) owns one :class:`Supervisor` and
calls it from its own thread only. Starting a worker cold costs an interpreter and the imports of
numpy, scipy and OpenCV (``docs/performance.md``, "Worker start-up"), too slow for reconfiguration,
so the supervisor keeps a **warm pool** of idle members (``python -m ubitrack_agent.services.worker
--pool-id ID``, :class:`ubitrack_agent.services.worker.Pool`) that have imported everything and wait
for a specification on ``<root>/pool/<ID>``:

* start: hand the specification to a ready member (its pool token is up); with none ready,
  start a fresh process with ``--spec`` (it joins the pool once released);
* refill: one process at a time, and only after ``REFILL_QUIET_S`` without a start, so the
  imports never compete with a data flow that has just been rewired;
* stop: put the stop command on the instance's control key and keep the process as
  *releasing*: the stop is put again every ``STOP_RESEND_S`` (a process still starting, not yet
  subscribed to its control key, would miss a single one) until the process confirms it by
  declaring its pool token again, which it does only once its run has ended; only then does it
  count as a pool member (or, with the pool full, is it terminated). Not confirmed within
  ``STOP_GRACE_S``, it is terminated (SIGTERM), and killed (SIGKILL) ``STOP_GRACE_S`` later; a
  process stopped is owned until it has exited, so no stop is ever lost;
* a start of an instance whose earlier process is still releasing terminates that process, so
  one instance never runs twice here and no stop meant for it reaches the new one;
* a pool member not ready within ``POOL_READY_S`` (spawned, or its pool token vanished) is
  terminated, so a stuck member never stops the pool from refilling; a token awaited for over
  ``TOKEN_ASK_S`` (a member's, or a container's) is asked for every ``TOKEN_ASK_S`` before
  that (:meth:`Supervisor.awaited_tokens`): a declaration the router holds but did not pass
  on to the liveliness subscriber is found instead of the process being terminated;
* a pool token appearing for a process that runs an instance means a stop command from
  elsewhere released it: the instance ended (reported, like a process that exited).

**Containers** (:mod:`ubitrack_agent.services.container`): a group's components run in one process
named by the group. A start of a group whose container does not run hands the group to a ready pool
member, which becomes the container (with none ready, a member still starting, else a fresh
one spawned, is given the group once its pool token is up: a group is too large for a command
line); one whose container
runs adds the components to it with an ``add`` command (no process start), sent once the
container's token shows it takes commands. A stop of a component in a container removes it
from there (``remove``); a container left with no component for ``EMPTY_GRACE_S`` is stopped.
A container whose
process exits unasked is started again, in one batch, by a ready pool
member if there is one, with the components it ran (**restored**, each reported
as such with the new process's pid, under its old run: the agent sends their current wiring),
at most ``MAX_QUICK_RESTORES`` times in a row within ``QUICK_RESTORE_S`` of its start; then its
components are reported as exited. A component that left its container by its own stop
command (``<root>/left/<name>``) is reported as released. A component rewired in place (its
control command, which the host manager reads too) is restored as rewired (:meth:`rewire`).
A container that a host manager of this name left running when it died is **adopted**
(:meth:`adopt`, :mod:`ubitrack_agent.services.adoption`): its components are assigned to it
under new runs, and it is stopped, emptied and restored as if started here.

Only the worker module runs, without a shell, the specification as one argument; every member
reads a pipe from this process as its standard input, so idle members, and workers still
starting (no worker token yet), exit with the host manager, while workers serving keep running
(a restarted agent adopts them; :mod:`ubitrack_agent.services.parent`).
"""

from __future__ import annotations

import json
import logging
import subprocess
import sys
import time
import uuid
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from ubitrack_agent.core.interpreter import module_command
from ubitrack_agent.net import config
from ubitrack_agent.net.host_protocol import (
    STOP_COMMAND,
    Exited,
    ProtocolError,
    Started,
    StartedGroup,
)
from ubitrack_agent.net.json_messages import MessageError, load_object
from ubitrack_agent.net.keys import KeySpace, validate_key_chunks
from ubitrack_agent.net.spec import ComponentSpec, GroupSpec
from ubitrack_agent.net.transport import put_command
from ubitrack_agent.services.adoption import UNKNOWN_EXIT, AdoptedProcess, Orphan

log = logging.getLogger("ubitrack.host")

STOP_GRACE_S = 3.0
"""How long a stopped worker may take to exit (or a released one to rejoin the pool) before it
is terminated, and a terminated one before it is killed."""
STOP_RESEND_S = 0.5
"""A stop not yet confirmed is put again this often."""
REFILL_QUIET_S = 3.0
"""The pool is topped up only after this long without a component being started."""
POOL_READY_S = 20.0
"""A pool member whose pool token is not up this long after it was spawned (or after its token
vanished) is terminated; so is a container whose token is not up this long after its start."""
TOKEN_ASK_S = 2.0
"""A token awaited this long is asked for (a liveliness query), again every this often until
it is up or ``POOL_READY_S`` passes. Once in CI (access control on, 2,440 tests passing beside
it) a container serving its components was terminated twice as never ready: its token never
reached the host manager's subscriber."""
QUICK_RESTORE_S = 10.0
"""A container that dies sooner than this after its start died quickly."""
MAX_QUICK_RESTORES = 3
"""A container that died quickly this many times in a row is not restored again."""
EMPTY_GRACE_S = 1.0
"""A container without a component is stopped after this long (a component restarted with
another specification is removed and added again: its container stays)."""
MAX_LEFT_BYTES = 64 * 1024
"""Largest report of components that left a container read."""


@dataclass
class Assignment:
    """A worker process running an instance: ``run`` names this start of it; ``container``
    the container it runs in (None: a process of its own)."""

    spec: ComponentSpec
    run: str
    pool_id: str
    process: subprocess.Popen | AdoptedProcess
    container: str | None = None


@dataclass
class ContainerRun:
    """A container process: its pool id, its incarnation once its token is up (it takes
    commands on its own control key), the commands waiting for that, and the group it is still
    to be given (a member spawned for it gets it once its pool token is up)."""

    name: str
    pool_id: str
    process: subprocess.Popen | AdoptedProcess
    """Its process: this supervisor's child, or an adopted one (:meth:`Supervisor.adopt`)."""
    started: float
    incarnation: str | None = None
    """Its process's incarnation once its token is up (it takes commands)."""
    pending: list[str] = field(default_factory=list)
    group: str | None = None
    quick_restores: int = 0
    taken_from: str = "pool"
    """Which process took the group: ``pool`` (a ready member), ``starting`` (a member still
    importing) or ``cold`` (spawned for it)."""
    empty_since: float | None = None


@dataclass
class Release:
    """A process told to stop running ``instance``, until it confirms (its pool token)."""

    instance: str
    process: subprocess.Popen
    deadline: float
    resend_at: float


class Supervisor:
    """The worker processes this host manager started (see the module docstring)."""

    def __init__(
        self,
        session: Any,
        keys: KeySpace,
        worker_flags: Sequence[str],
        pool_size: int,
        counters: Counter[str],
        python: str = sys.executable,
    ) -> None:
        self._session = session
        self._keys = keys
        self._flags = list(worker_flags)
        self._python = python
        self.pool_size = pool_size
        self.counters = counters
        self._tag = uuid.uuid4().hex[:6]
        self._members: dict[str, subprocess.Popen] = {}
        """Idle pool members by pool id: ready, starting, or returning after a release."""
        self._ready: set[str] = set()
        self._unready_since: dict[str, float] = {}
        """Members without their pool token up, by pool id: since when."""
        self._releasing: dict[str, Release] = {}
        """Processes told to stop, by pool id, until they confirm."""
        self.assigned: dict[str, Assignment] = {}
        self.containers: dict[str, ContainerRun] = {}
        self._stopping: list[tuple[subprocess.Popen | AdoptedProcess, float]] = []
        self._last_start = -REFILL_QUIET_S
        self._tokens_asked_at = -TOKEN_ASK_S
        self.last_restore: dict[str, Any] | None = None
        """The latest container restored: its name, components, which process took it
        (:attr:`ContainerRun.taken_from`), when its death was noticed and when the process was
        given the group or spawned for it (wall clock, ns): the restore's parts here
        (``bench.restore_parts``)."""

    # -- pool ---------------------------------------------------------------------------------

    def _spawn(self, pool_id: str, *arguments: str) -> subprocess.Popen:
        process = subprocess.Popen(
            module_command(
                "ubitrack_agent.services.worker",
                *("--pool-id", pool_id, *arguments, *self._flags),
                python=self._python,
            ),
            stdin=subprocess.PIPE,  # closes when the host manager ends: idle members then exit
            env=config.child_environment(),  # its network from its flags alone
        )
        return process

    def fill_pool(self) -> None:
        """Start one pool member if the pool is short, none is starting and starts have been
        quiet for ``REFILL_QUIET_S``."""
        starting = set(self._members) - self._ready
        quiet = time.monotonic() - self._last_start > REFILL_QUIET_S
        if self._pool_has_room() and quiet and not starting:
            pool_id = f"{self._tag}-{uuid.uuid4().hex[:8]}"
            try:
                self._members[pool_id] = self._spawn(pool_id)
                self._unready_since[pool_id] = time.monotonic()
            except OSError as exc:
                self.counters["failed_pool_spawns"] += 1
                self._last_start = time.monotonic()  # try again after a quiet period
                log.error("cannot start a pool worker: %s", exc)

    def on_pool_token(self, pool_id: str, appeared: bool) -> Exited | None:
        """A pool token appeared or vanished; the instance it ended, if its process was
        running one (released by a stop command this host manager did not send)."""
        if not appeared:
            if pool_id in self._ready:
                self._ready.discard(pool_id)
                self._unready_since[pool_id] = time.monotonic()
            return None
        if pool_id in self._members:
            self._ready.add(pool_id)
            self._unready_since.pop(pool_id, None)
            return None
        release = self._releasing.pop(pool_id, None)
        if release is not None:
            self.counters["stops_confirmed"] += 1
            self._rejoin(pool_id, release.process)
            return None
        box = next((b for b in self.containers.values() if b.pool_id == pool_id), None)
        if box is not None:
            if box.group is not None:  # spawned for the container: its group now
                put_command(self._session, self._keys.pool(pool_id), box.group)
                box.group = None
            return None
        owner = next((i for i, a in self.assigned.items() if a.pool_id == pool_id), None)
        if owner is None:
            return None  # another host manager's member
        assignment = self.assigned.pop(owner)
        self.counters["released"] += 1
        log.info("%s: released by a stop command from elsewhere", owner)
        self._rejoin(pool_id, assignment.process)
        return Exited(owner, assignment.run, assignment.process.pid, None, "released")

    def awaited_tokens(self, now: float) -> list[tuple[str, str]]:
        """The tokens to ask for now, as ``(kind, selector)``: ``container`` if a container's
        token has been awaited for over ``TOKEN_ASK_S``, ``pool`` if a member's (or that of a
        process spawned for a container) has; at most once every ``TOKEN_ASK_S``. O(members +
        containers); each query's replies are every token of its kind
        (:meth:`on_container_token_found`, :meth:`on_pool_token_found`)."""
        if now - self._tokens_asked_at < TOKEN_ASK_S:
            return []
        late = now - TOKEN_ASK_S
        asked = []
        if any(b.incarnation is None and b.started < late for b in self.containers.values()):
            asked.append(("container", self._keys.all_containers()))
        spawned = (b for b in self.containers.values() if b.group is not None)
        if any(since < late for since in self._unready_since.values()) or any(
            b.started < late for b in spawned
        ):
            asked.append(("pool", self._keys.all_pools()))
        if asked:
            self._tokens_asked_at = now
        return asked

    def on_container_token_found(self, name: str, incarnation: str) -> None:
        """A container's token found by asking (:meth:`awaited_tokens`): as if it appeared,
        counted (``tokens_found``) if its container was waiting for it."""
        box = self.containers.get(name)
        if box is not None and box.incarnation is None:
            self.on_container_token(name, incarnation, appeared=True)
            if box.incarnation is not None:
                self.counters["tokens_found"] += 1

    def on_pool_token_found(self, pool_id: str) -> None:
        """A pool token found by asking (:meth:`awaited_tokens`): as if it appeared, counted
        (``tokens_found``), only for a member still awaited or a process spawned for a
        container still to be given its group. Any other (a member taken since, which a reply
        may predate; another host manager's) is left alone: taken as appearing, it would read
        as a release by a stop from elsewhere."""
        boxes = self.containers.values()
        spawned = any(b.pool_id == pool_id and b.group is not None for b in boxes)
        if pool_id in self._unready_since or spawned:
            self.counters["tokens_found"] += 1
            self.on_pool_token(pool_id, appeared=True)

    def _pool_has_room(self) -> bool:
        """Whether the pool (members and processes returning to it) is short."""
        return len(self._members) + len(self._releasing) < self.pool_size

    def _rejoin(self, pool_id: str, process: subprocess.Popen) -> None:
        """A process that ended its run and showed its pool token: a ready member if the pool
        is short, else terminated."""
        if len(self._members) < self.pool_size:
            self._members[pool_id] = process
            self._ready.add(pool_id)
        else:
            self._terminate(process)

    def _take_ready(self) -> tuple[str, subprocess.Popen] | None:
        while self._ready:
            pool_id = self._ready.pop()
            process = self._members.pop(pool_id)
            self._unready_since.pop(pool_id, None)
            if process.poll() is None:
                return pool_id, process
        return None

    def _take_starting(self) -> tuple[str, subprocess.Popen] | None:
        """A pool member still starting (its imports under way), the one spawned first: a
        container given to it runs sooner than in a process spawned now, which would compete
        with it for the CPU."""
        for pool_id in sorted(self._unready_since, key=self._unready_since.__getitem__):
            process = self._members.get(pool_id)
            if process is not None and process.poll() is None:
                del self._members[pool_id], self._unready_since[pool_id]
                return pool_id, process
        return None

    # -- instances ----------------------------------------------------------------------------

    def start(self, spec: ComponentSpec) -> Started:
        """Run ``spec`` (already checked against the registry). A repeated start of an instance
        running with the same specification starts nothing; with another, the running one is
        stopped first, so one instance never runs twice here."""
        current = self.assigned.get(spec.instance)
        if current is not None and current.container is not None:
            self.stop(spec.instance)  # moves out of its container
        elif current is not None and current.process.poll() is None:
            if current.spec == spec:
                self.counters["reused"] += 1
                return Started(spec.instance, current.run, current.process.pid, reused=True)
            self.stop(spec.instance)
        self._terminate_releases_of(spec.instance)
        taken = self._take_ready()
        if taken is not None:
            pool_id, process = taken
            put_command(self._session, self._keys.pool(pool_id), spec.to_json())
            self.counters["started_from_pool"] += 1
            log.info("%s: assigned to pool worker %s", spec.instance, pool_id)
        else:
            pool_id = f"{self._tag}-{uuid.uuid4().hex[:8]}"
            try:
                process = self._spawn(pool_id, "--spec", spec.to_json())
            except OSError as exc:
                raise ProtocolError("failed_spawn", str(exc)) from None
            self.counters["started_cold"] += 1
            log.info("%s: started process %d", spec.instance, process.pid)
        run = uuid.uuid4().hex[:12]
        self.assigned[spec.instance] = Assignment(spec, run, pool_id, process)
        self._last_start = time.monotonic()
        return Started(spec.instance, run, process.pid, reused=False)

    def start_group(self, group: GroupSpec) -> StartedGroup:
        """Run ``group``'s components (already checked against the registry) in its container:
        started with them if it does not run, else added to it (module docstring). A component
        already running there with the same specification starts nothing; one running elsewhere
        on this host, or there with another specification, is stopped first."""
        box = self.containers.get(group.container)
        started, new = [], []
        for spec in group.components:
            current = self.assigned.get(spec.instance)
            here = current is not None and current.container == group.container
            if box is not None and here and current.spec == spec:
                self.counters["reused"] += 1
                started.append(Started(spec.instance, current.run, box.process.pid, True))
                continue
            if current is not None:
                self.stop(spec.instance)
            self._terminate_releases_of(spec.instance)
            new.append(spec)
        if box is None:
            box = self._start_container(GroupSpec(group.container, tuple(new)))
        elif new:
            self._send(box, json.dumps({"add": [spec.as_dict() for spec in new]}))
            self.counters["added_to_containers"] += len(new)
        for spec in new:
            run = uuid.uuid4().hex[:12]
            self.assigned[spec.instance] = Assignment(
                spec, run, box.pool_id, box.process, group.container
            )
            started.append(Started(spec.instance, run, box.process.pid, reused=False))
        if new:
            self._last_start = time.monotonic()
        return StartedGroup(group.container, box.process.pid, tuple(started))

    def _start_container(self, group: GroupSpec, quick_restores: int = 0) -> ContainerRun:
        """A container process for ``group``: a ready pool member given the group, else a
        member spawned to be given it once ready; :class:`ProtocolError` if none can start."""
        taken = self._take_ready()
        starting = self._take_starting() if taken is None else None
        if taken is not None:
            pool_id, process = taken
            put_command(self._session, self._keys.pool(pool_id), group.to_json())
            pending_group, taken_from = None, "pool"
            self.counters["containers_from_pool"] += 1
        elif starting is not None:
            pool_id, process = starting
            pending_group = group.to_json()
            self.counters["containers_from_starting_members"] += 1
            taken_from = "starting"
        else:
            pool_id = f"{self._tag}-{uuid.uuid4().hex[:8]}"
            try:
                process = self._spawn(pool_id)
            except OSError as exc:
                raise ProtocolError("failed_spawn", str(exc)) from None
            pending_group = group.to_json()
            self.counters["containers_cold"] += 1
            taken_from = "cold"
        log.info(
            "container %s: %d components, process %d",
            group.container,
            len(group.components),
            process.pid,
        )
        box = ContainerRun(
            group.container,
            pool_id,
            process,
            time.monotonic(),
            group=pending_group,
            quick_restores=quick_restores,
            taken_from=taken_from,
        )
        self.containers[group.container] = box
        return box

    def _send(self, box: ContainerRun, command: str) -> None:
        """Put ``command`` on the control key of ``box``'s process, or keep it until its token
        is up (another process of the same name, left by an earlier host manager, never
        hears it)."""
        if box.incarnation is not None:
            key = self._keys.control_incarnation(box.name, box.incarnation)
            put_command(self._session, key, command)
        else:
            box.pending.append(command)

    def on_container_token(self, name: str, incarnation: str, appeared: bool) -> None:
        """A container's token appeared: it takes commands (those waiting are sent). Tokens
        of another process than the container's, and a token vanishing (the process ends:
        :meth:`reap` sees it), change nothing."""
        box = self.containers.get(name)
        if not appeared or box is None or incarnation.partition(".")[0] != str(box.process.pid):
            return
        box.incarnation = incarnation
        for command in box.pending:
            self._send(box, command)
        box.pending.clear()

    def on_left(self, name: str, payload: bytes) -> list[Exited]:
        """Components that left container ``name`` without its remove (its report on
        ``<root>/left/<name>``): by their own stop command (reported as released), or because
        they failed to start there (reported as exited). :class:`ProtocolError` if the
        report is malformed."""
        try:
            report = load_object(payload, MAX_LEFT_BYTES)
        except MessageError as exc:
            raise ProtocolError(exc.error, exc.reason) from None
        instances, incarnation = report.get("instances"), report.get("incarnation")
        if not isinstance(instances, list) or not isinstance(incarnation, str):
            raise ProtocolError("malformed_request", "left: expected instances and incarnation")
        reason = report.get("reason", "released")
        if reason not in ("released", "exited"):
            raise ProtocolError("malformed_request", "left: reason released or exited")
        box = self.containers.get(name)
        if box is None or incarnation.partition(".")[0] != str(box.process.pid):
            return []  # another process's (an earlier one, or not this host manager's)
        exits = []
        for instance in instances:
            try:
                validate_key_chunks(instance, single_chunk=True)
            except (TypeError, ValueError) as exc:
                raise ProtocolError("malformed_request", f"left: {exc}") from None
            assignment = self.assigned.get(instance)
            if assignment is not None and assignment.container == name:
                del self.assigned[instance]
                self.counters["released" if reason == "released" else "failed_in_containers"] += 1
                log.info("%s: left container %s (%s)", instance, name, reason)
                exits.append(Exited(instance, assignment.run, box.process.pid, None, reason))
        return exits

    def adopt(self, orphan: Orphan) -> int:
        """Take ``orphan``, a container a host manager of this name left running when it died,
        as if this supervisor had started it: each component assigned under a new run (the
        agent learns them from the status), its process watched in ``/proc``. The components
        adopted: none if the process has ended, or its name or a component of it runs here
        already (then the agent, which stops a duplicate process, decides). O(components)."""
        process = AdoptedProcess(orphan.pid, orphan.worker.started)
        taken = orphan.name in self.containers or any(
            spec.instance in self.assigned for spec in orphan.specs
        )
        if taken or not orphan.specs or process.poll() is not None:
            self.counters["orphans_left"] += 1
            log.warning("container %s (process %d) not adopted", orphan.name, orphan.pid)
            return 0
        pool_id = orphan.worker.pool_id
        box = ContainerRun(orphan.name, pool_id, process, time.monotonic(), orphan.incarnation)
        self.containers[orphan.name] = box
        for spec in orphan.specs:
            run = uuid.uuid4().hex[:12]
            self.assigned[spec.instance] = Assignment(spec, run, pool_id, process, orphan.name)
        self.counters["containers_adopted"] += 1
        self.counters["components_adopted"] += len(orphan.specs)
        log.warning(
            "container %s (process %d) adopted with %d components",
            orphan.name,
            orphan.pid,
            len(orphan.specs),
        )
        return len(orphan.specs)

    def knows_container(self, name: str, pid: int) -> bool:
        """Whether container ``name`` runs here in process ``pid``."""
        box = self.containers.get(name)
        return box is not None and box.process.pid == pid

    def spec_of(self, instance: str) -> ComponentSpec | None:
        """The current specification of ``instance`` if it runs here, else None."""
        assignment = self.assigned.get(instance)
        return None if assignment is None else assignment.spec

    def rewire(self, spec: ComponentSpec) -> None:
        """``spec``'s instance, running here, was rewired in place to ``spec`` (its control
        command): a restore or a repeated start goes by it."""
        self.assigned[spec.instance].spec = spec

    def stop(self, instance: str) -> str:
        """Put the stop command on ``instance``'s control key (wherever it runs) and release
        or terminate its process here: ``"released"`` (it returns to the pool once it confirms,
        module docstring), ``"terminated"`` or ``"none"``; for a component in a container,
        remove it from there (``"removed"``)."""
        assignment = self.assigned.get(instance)
        if assignment is not None and assignment.container is not None:
            del self.assigned[instance]
            self.counters["stopped"] += 1
            box = self.containers.get(assignment.container)
            if box is not None:
                self._send(box, json.dumps({"remove": [instance]}))
            return "removed"
        put_command(self._session, self._keys.control(instance), STOP_COMMAND)
        assignment = self.assigned.pop(instance, None)
        if assignment is None:
            return "none"
        self.counters["stopped"] += 1
        process = assignment.process
        if process.poll() is None and self._pool_has_room():
            now = time.monotonic()
            release = Release(instance, process, now + STOP_GRACE_S, now + STOP_RESEND_S)
            self._releasing[assignment.pool_id] = release
            return "released"
        self._terminate(process)
        return "terminated"

    def _terminate_releases_of(self, instance: str) -> None:
        """Terminate the processes still releasing ``instance`` (it is starting again)."""
        for pool_id, release in list(self._releasing.items()):
            if release.instance == instance:
                del self._releasing[pool_id]
                self._terminate(release.process)

    def _terminate(self, process: subprocess.Popen | AdoptedProcess) -> None:
        if process.poll() is None:
            process.terminate()
            self._stopping.append((process, time.monotonic() + STOP_GRACE_S))

    def reap(self) -> list[Exited]:
        """Collect exited processes, kill overdue ones; the instances whose process exited."""
        exits = self._look_after_containers()
        for instance, assignment in list(self.assigned.items()):
            if assignment.container is not None:
                continue
            returncode = assignment.process.poll()
            if returncode is not None:
                del self.assigned[instance]
                self.counters["exited"] += 1
                log.warning("%s: worker exited with %s", instance, returncode)
                pid = assignment.process.pid
                exits.append(Exited(instance, assignment.run, pid, returncode, "exited"))
        now = time.monotonic()
        self._follow_releases(now)
        for pool_id, since in list(self._unready_since.items()):
            if now - since > POOL_READY_S:
                log.warning(
                    "pool worker %s not ready for %.0f s: terminating it", pool_id, now - since
                )
                self.counters["unready_members"] += 1
                del self._unready_since[pool_id]
                self._ready.discard(pool_id)
                self._terminate(self._members.pop(pool_id))
        still = []
        for process, deadline in self._stopping:
            if process.poll() is None:
                if now > deadline:
                    self.counters["killed"] += 1
                    process.kill()
                still.append((process, deadline))
        self._stopping = still
        for pool_id in [p for p, process in self._members.items() if process.poll() is not None]:
            del self._members[pool_id]
            self._ready.discard(pool_id)
            self._unready_since.pop(pool_id, None)
        return exits

    def _look_after_containers(self) -> list[Exited]:
        """Restore the containers whose process exited (or that never became ready), end those
        left without a component; the components restored, or ended if their container cannot
        be restored (module docstring)."""
        now = time.monotonic()
        members: dict[str, list[tuple[str, Assignment]]] = {name: [] for name in self.containers}
        for instance, assignment in self.assigned.items():
            if assignment.container in members:
                members[assignment.container].append((instance, assignment))
        exits: list[Exited] = []
        for name, box in list(self.containers.items()):
            returncode = box.process.poll()
            if returncode is None and box.incarnation is None and now - box.started > POOL_READY_S:
                log.warning("container %s not ready for %.0f s: terminating it", name, POOL_READY_S)
                self.counters["unready_containers"] += 1
                box.process.kill()
                returncode = box.process.wait()
            if returncode is None:
                if members[name]:
                    box.empty_since = None
                elif box.empty_since is None:
                    box.empty_since = now
                elif now - box.empty_since > EMPTY_GRACE_S:
                    self._end_container(box)
                continue
            del self.containers[name]
            if not members[name]:
                continue
            self.counters["containers_exited"] += 1
            log.warning("container %s exited with %s", name, returncode)
            exits += self._restore(box, members[name], returncode, now)
        return exits

    def _restore(
        self,
        box: ContainerRun,
        members: list[tuple[str, Assignment]],
        returncode: int | None,
        now: float,
    ) -> list[Exited]:
        """Start ``box``'s container again with ``members``; their reports."""
        noticed_ns = time.time_ns()
        quick = box.quick_restores + 1 if now - box.started < QUICK_RESTORE_S else 0
        group = GroupSpec(box.name, tuple(assignment.spec for _, assignment in members))
        if returncode == UNKNOWN_EXIT:  # an adopted process: its status was its parent's
            returncode = None
        try:
            if quick > MAX_QUICK_RESTORES:
                raise ProtocolError(
                    "failed_spawn", f"died {quick} times within {QUICK_RESTORE_S} s"
                )
            new = self._start_container(group, quick)
        except ProtocolError as exc:
            log.error("container %s not restored: %s", box.name, exc)
            for instance, _ in members:
                del self.assigned[instance]
            return [
                Exited(instance, a.run, box.process.pid, returncode, "exited")
                for instance, a in members
            ]
        self.counters["containers_restored"] += 1
        self.last_restore = {
            "container": box.name,
            "components": len(members),
            "taken_from": new.taken_from,
            "noticed_ns": noticed_ns,
            "started_ns": time.time_ns(),
        }
        for _, assignment in members:
            assignment.process, assignment.pool_id = new.process, new.pool_id
        return [
            Exited(instance, a.run, new.process.pid, returncode, "restored")
            for instance, a in members
        ]

    def _end_container(self, box: ContainerRun) -> None:
        """Stop a container left without a component: its stop command once it takes commands
        (killed if it has not ended ``STOP_GRACE_S`` later), else SIGTERM."""
        del self.containers[box.name]
        self.counters["containers_ended"] += 1
        if box.incarnation is not None:
            self._send(box, STOP_COMMAND)
            self._stopping.append((box.process, time.monotonic() + STOP_GRACE_S))
        else:
            self._terminate(box.process)

    def _follow_releases(self, now: float) -> None:
        """Forget releasing processes that exited, put the stop again to those that did not
        confirm yet, terminate those past their deadline."""
        for pool_id, release in list(self._releasing.items()):
            if release.process.poll() is not None:
                del self._releasing[pool_id]
            elif now > release.deadline:
                del self._releasing[pool_id]
                self.counters["unconfirmed_stops"] += 1
                log.warning(
                    "%s: process %d did not confirm its stop: terminating it",
                    release.instance,
                    release.process.pid,
                )
                self._terminate(release.process)
            elif now > release.resend_at:
                release.resend_at = now + STOP_RESEND_S
                self.counters["stops_resent"] += 1
                put_command(self._session, self._keys.control(release.instance), STOP_COMMAND)

    def terminate_all(self) -> None:
        """End every process this supervisor started (the host manager is stopping cleanly)."""
        everything = [a.process for a in self.assigned.values()]
        everything += [box.process for box in self.containers.values()]
        everything += [*self._members.values(), *(process for process, _ in self._stopping)]
        everything += [release.process for release in self._releasing.values()]
        for process in everything:
            if process.poll() is None:
                process.terminate()
        deadline = time.monotonic() + STOP_GRACE_S  # one grace for all, not one each
        for process in everything:
            try:
                process.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
        self.assigned.clear()
        self.containers.clear()
        self._members.clear()
        self._ready.clear()
        self._unready_since.clear()
        self._releasing.clear()
        self._stopping.clear()

    def status(self) -> dict[str, Any]:
        """Pool and instances (JSON-ready)."""
        return {
            "pool_size": self.pool_size,
            "pool_ready": len(self._ready),
            "pool_starting": len(self._members) - len(self._ready),
            "releasing": len(self._releasing),
            "stopping": len(self._stopping),
            "last_restore": self.last_restore,
            "instances": {
                instance: {
                    "service": assignment.spec.service,
                    "run": assignment.run,
                    "pid": assignment.process.pid,
                    "pool_id": assignment.pool_id,
                    "container": assignment.container,
                }
                for instance, assignment in self.assigned.items()
            },
            "containers": {
                name: {"pid": box.process.pid, "ready": box.incarnation is not None}
                for name, box in self.containers.items()
            },
        }
