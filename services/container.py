"""A container: one worker process hosting any number of component instances.

Start: ``python -m ubitrack_agent.services.container --name NAME [--group '<json>'] [zenoh flags]``
(a :class:`~ubitrack_agent.net.spec.GroupSpec`). Where the worker
(:mod:`ubitrack_agent.services.worker`) runs one component per process, paying an interpreter, the
imports of numpy, scipy and OpenCV and a zenoh session for each (issue 28: about 75 MB and a session
linked to every other per component), a container runs many on one session, each a
:class:`~ubitrack_agent.services.worker.Worker` as before: its own control keys, status, counters
and liveliness token, so the agent, ``ubitrack status`` and the web view see one component as they
always did (its status names its ``container``). What a worker process does on a thread per
component, a container does on one (:mod:`ubitrack_agent.services.scheduler`): the components'
control commands, status queries, held triggers, static inputs' samples and fetches, so adding a
component starts no thread of its own (its dynamic inputs read over zenoh have one each,
``net.transport.subscribe_in_bursts``; its publishers' queries are answered by the process's
answering threads, ``net.transport.ANSWERS``). The anchors are ROS 2's component containers
(composable nodes loaded into a running process, ``ros2 component load``, with intra-process
communication) and dora-rs's operators sharing a runtime process; the paper's service managers
run the pattern instances of a host (Pustka et al. 2006, section 5.2.1).

**Wires inside.** A component reading another's output in the same container is handed the
measurement object (:mod:`ubitrack_agent.services.local_wires`): no encoding, no decoding, no zenoh.
Zenoh carries an output only where something outside the process reads it: a subscriber in another
process or host (the publisher's matching status), an application's relation key, a query
for a value at a given time (answered by the producer's queryable, as before).

**Control** on ``<root>/control/<name>``, and on ``<root>/control/<name>/<incarnation>`` for
this process alone (how its host manager talks to it: a container of the same name left
running by an earlier host manager does not hear it), JSON objects, read totally (a malformed
or refused command is logged rate-limited, counted in ``rejected_commands`` and changes
nothing; one whose attachment names another key, ``net.address``, in ``misaddressed``):

* ``{"add": [<specification>, ...]}`` starts components in the running process (checked in
  full first: form, registered service and ports, parameters, no instance already in the
  container; all or none);
* ``{"remove": ["<instance>", ...]}`` stops them (an unknown name is ignored);
* ``{"stop": true}`` ends the container and every component in it.

A component is rewired, reconfigured or stopped on its own control key as before (a stop
there removes it, and is reported on ``<root>/left/<name>``, so the host manager that runs the
container forgets it). Adding, removing or rewiring starts no process; the readers of an output
whose producer joined or left the container bind again (locally, or over zenoh), keeping their
history.

**Failure containment.** Every handler of a component is total (its own counters); an
unexpected exception is counted there (``internal_errors``) and the others go on. A component
with :data:`RESTART_AFTER_FAULTS` such faults since it started, or that stopped without being
asked, is restarted in the process from its current specification (counted: ``restarts``, per
component in the container's status). A component whose code never returns on the
scheduler's thread holds back the others' turns (not their data): isolation, a container of
its own, is for such code. SIGTERM or SIGINT ends the container cleanly.

The container's own status answers on ``<root>/status/<name>`` (no ``instance`` field: it is
no component's; each component's current specification, by which a host manager adopts a
container whose own host manager died: :mod:`ubitrack_agent.services.adoption`). Once it
takes commands it declares the liveliness token
``<root>/container/<name>/<incarnation>`` (``<pid>.<nonce>``): its host manager sends it
commands only from then on. Started by a host manager (``parent``,
:mod:`ubitrack_agent.services.parent`), it exits while starting if the host manager is gone, and
outlives it once its token is up (a restarted agent adopts its components, and the next host
manager of its name the container), until its last component has left (then nobody would stop
it).

Growth: memory and zenoh declarations O(components + their inputs and outputs); threads O(1)
for the container (its scheduler, the process's hand-over thread, ``services.handover``, and
input starter, ``net.transport.STARTER``, and at most ``net.transport.ANSWERING_THREADS``
answering queries) plus one per dynamic input read over zenoh
(``net.transport.subscribe_in_bursts``); a hand-over O(readers of the output). An ``add``
costs O(the components added + their inputs and outputs), whatever the container holds: the
running components are looked up by name (:meth:`Container.check`), a key's producers and
readers by key (``LocalWires``), and the add waits for no thread to start
(``docs/performance.md``, "First sample for 100 applications, session 21").
"""

from __future__ import annotations

import argparse
import functools
import json
import logging
import os
import queue
import sys
import threading
import time
import uuid
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from ubitrack_agent.core.heap import settle_collector
from ubitrack_agent.net import config, logs
from ubitrack_agent.net.address import is_misaddressed, tag
from ubitrack_agent.net.clock import Clock
from ubitrack_agent.net.encodings import JSON
from ubitrack_agent.net.json_messages import MessageError, load_object
from ubitrack_agent.net.keys import KeySpace, validate_key_chunks
from ubitrack_agent.net.lifecycle import on_termination
from ubitrack_agent.net.spec import (
    MAX_GROUP_COMPONENTS,
    ComponentSpec,
    GroupSpec,
    SpecError,
    check_group_members,
    parse_components,
    parse_group,
)
from ubitrack_agent.net.transport import on_zenoh_thread
from ubitrack_agent.services.local_wires import LocalWires
from ubitrack_agent.services.parent import Parent
from ubitrack_agent.services.scheduler import Scheduler
from ubitrack_agent.services.spec import check_spec
from ubitrack_agent.services.start_order import start_order
from ubitrack_agent.services.worker import Worker

log = logging.getLogger("ubitrack.container")

RESTART_AFTER_FAULTS = 20
"""Unexpected exceptions (``internal_errors``) a component may raise since it started before
the container restarts it with a fresh state."""
LOOP_S = 0.25
"""Longest wait of the container's thread for a command before it looks at its components
(a stop wakes it)."""
JOIN_S = 2.0
"""How long the scheduler's thread may take to end once the container stopped."""
MAX_CONTROL_BYTES = 4 * 1024 * 1024
"""Largest container command read (an ``add`` of a thousand specifications)."""
CONTROL_FIELDS = frozenset({"add", "remove", "stop"})

COUNTERS = {
    "added": "components started in the running container",
    "removed": "components stopped by a remove command or their own stop command",
    "restarts": "components restarted after faults, or after their thread ended unasked",
    "rebinds": "components whose inputs were bound again (a producer joined or left)",
    "rejected_commands": "container commands refused (malformed, or not all components valid)",
    "misaddressed": "container commands refused as put on another key than the one they came "
    "on (net.address: zenoh delivered them there)",
    "failed_starts": "components whose start failed unexpectedly (logged with traceback)",
    "internal_errors": "unexpected exceptions of the container itself (logged with traceback)",
}
"""The container's own counters (its status); each component keeps its own."""


@dataclass
class Running:
    """A component running in the container: its worker, its faults when it (re)started and
    how often it was restarted."""

    worker: Worker
    faults_at_start: int = 0
    restarts: int = 0


class Container:
    """Runs components on an open zenoh ``session`` until :meth:`stop` (module docstring)."""

    def __init__(
        self,
        session: Any,
        keys: KeySpace,
        name: str,
        clock: Clock | None = None,
        components: Iterable[ComponentSpec] = (),
        parent: Parent | None = None,
    ) -> None:
        self.name = validate_key_chunks(name, single_chunk=True)
        self.keys = keys
        self.clock = clock or Clock()
        self.counters: Counter[str] = Counter(dict.fromkeys(COUNTERS, 0))
        self.incarnation = f"{os.getpid()}.{uuid.uuid4().hex[:8]}"
        self.wires = LocalWires()
        self.wires.changed = lambda moved: self._events.put(("moved", moved))
        self.components: dict[str, Running] = {}
        self._session = session
        self._lock = threading.Lock()
        """Held while :attr:`components` changes (the container's thread) or is read (status)."""
        self._events: queue.SimpleQueue[tuple[str, Any]] = queue.SimpleQueue()
        self._stop = threading.Event()
        self._parent = parent
        self.scheduler = Scheduler(self.name, self.counters)
        """Gives every component its turns (``ubitrack_agent.services.scheduler``): no thread per
        component."""
        self._controls = [
            session.declare_subscriber(
                key, on_zenoh_thread(self._guarded(self._control_handler(key)))
            )
            for key in (keys.control(self.name), keys.control_incarnation(name, self.incarnation))
        ]
        ask = self._guarded(
            lambda query: self.scheduler.call(functools.partial(self._reply, query))
        )
        self._status = session.declare_queryable(keys.status(self.name), on_zenoh_thread(ask))
        self._left = session.declare_publisher(keys.container_left(self.name), encoding=JSON)
        self._left_tag = tag(keys.container_left(self.name))
        self.add(tuple(components))
        declare = functools.partial(
            session.liveliness().declare_token, keys.container(self.name, self.incarnation)
        )
        self._token = declare() if parent is None else parent.serve(declare)

    # -- components ---------------------------------------------------------------------------

    def check(self, specs: tuple[ComponentSpec, ...]) -> None:
        """:class:`SpecError` unless every one of ``specs`` may join the container: a
        registered service wired as it declares (``ubitrack_agent.services.spec.check_spec``), and
        no instance name the container (or another of them) already has, nor more than
        ``net.spec.MAX_GROUP_COMPONENTS`` in all. O(specs): the running components are looked
        up by name, not listed."""
        for index, spec in enumerate(specs):
            try:
                check_spec(spec)
            except SpecError as exc:
                raise SpecError(f"add[{index}]: {exc}") from None
        check_group_members(specs, "add")
        with self._lock:
            running = len(self.components)
            present = [spec.instance for spec in specs if spec.instance in self.components]
        if present:
            raise SpecError(f"add: {present[0]!r} runs in the container already")
        if running + len(specs) > MAX_GROUP_COMPONENTS:
            raise SpecError(f"container.components: more than {MAX_GROUP_COMPONENTS}")

    def add(self, specs: tuple[ComponentSpec, ...]) -> None:
        """Start ``specs`` in this process (checked: :meth:`check`); their outputs are
        produced here from now on, so they and the running components read each other's
        locally. Started in the order that gets their relations flowing soonest
        (``ubitrack_agent.services.start_order``). O(producers x (specs + their bindings))."""
        self.check(specs)
        for spec in specs:  # before any starts: members read each other's outputs locally
            self.wires.produce(spec.instance, tuple(spec.outputs.values()))
        failed = []
        for spec in start_order(specs):
            if self._start(spec) is not None:
                self.counters["added"] += 1
            else:
                failed.append(spec.instance)
        if failed:  # its host manager reports them ended: the agent starts them again
            self._report_left(failed, "exited")

    def _start(self, spec: ComponentSpec, restarts: int = 0) -> Running | None:
        """Run ``spec``, its turns on the container's scheduler; None if it could not start
        (counted). O(its inputs and outputs): no thread started."""
        try:
            worker = Worker(
                spec,
                self._session,
                self.keys,
                clock=self.clock,
                wires=self.wires,
                container=self.name,
                scheduler=self.scheduler,
            )
        except Exception:
            self.wires.produce(spec.instance, ())
            logs.count_problem(
                self.counters,
                "failed_starts",
                log,
                "%s: %s did not start",
                self.name,
                spec.instance,
                exc_info=True,
            )
            return None
        entry = Running(worker, worker.faults, restarts)
        with self._lock:
            self.components[spec.instance] = entry
        self.scheduler.wake(worker, worker.turn)  # its first turn: its summaries' deadline
        log.info("%s: running %s (%s)", self.name, spec.instance, spec.service)
        return entry

    def remove(self, instances: Iterable[str]) -> None:
        """Stop the components named (the readers of their outputs bind over zenoh again)."""
        for instance in instances:
            with self._lock:
                entry = self.components.pop(instance, None)
            if entry is not None:
                self._end(entry)
                self.counters["removed"] += 1

    @staticmethod
    def _end(entry: Running) -> None:
        entry.worker.close()

    def _restart(self, instance: str, entry: Running, why: str) -> None:
        log.warning("%s: restarting %s (%s)", self.name, instance, why)
        with self._lock:
            self.components.pop(instance, None)
        self._end(entry)
        spec = entry.worker.spec  # as rewired since it started
        self.wires.produce(spec.instance, tuple(spec.outputs.values()))
        self.counters["restarts"] += 1
        self._start(spec, entry.restarts + 1)

    def _look_after(self) -> None:
        """Restart the components that faulted too often or stopped unasked; forget those a
        stop command on their own control key released (reported on ``<root>/left/<name>``).
        O(components)."""
        with self._lock:
            entries = list(self.components.items())
        left = []
        for instance, entry in entries:
            worker = entry.worker
            if worker.stopped:
                if worker.released:
                    with self._lock:
                        self.components.pop(instance, None)
                    self._end(entry)
                    self.counters["removed"] += 1
                    left.append(instance)
                else:
                    self._restart(instance, entry, "it stopped unasked")
            elif worker.faults - entry.faults_at_start >= RESTART_AFTER_FAULTS:
                self._restart(instance, entry, f"{RESTART_AFTER_FAULTS} unexpected faults")
        if left:
            self._report_left(left, "released")
        if self._parent is not None and self._parent.gone and not self.components:
            log.warning("%s: host manager gone and no component left: ending", self.name)
            self.stop()

    def _report_left(self, instances: list[str], reason: str) -> None:
        """Tell the host manager that ``instances`` left without its remove command: released
        by their own stop command, or ``exited`` (their start failed)."""
        report = {"instances": instances, "incarnation": self.incarnation, "reason": reason}
        self._left.put(json.dumps(report), attachment=self._left_tag)

    def _rebind(self, moved: set[str]) -> None:
        """Bind again the inputs reading ``moved`` keys (their producer joined or left).
        O(moved keys + their readers' inputs): the readers are looked up by key
        (``LocalWires.reading``), not searched among all the components."""
        readers = self.wires.reading(moved)
        with self._lock:
            workers = [self.components[name].worker for name in readers if name in self.components]
        for worker in workers:
            if worker.rebind():
                self.counters["rebinds"] += 1

    # -- control ------------------------------------------------------------------------------

    def _apply_control(self, payload: bytes) -> None:
        """Apply a container command in full, or refuse it (counted, logged)."""
        try:
            command = load_object(payload, MAX_CONTROL_BYTES)
            if not command or set(command) - CONTROL_FIELDS or len(command) != 1:
                raise SpecError(f"container: expected one of {sorted(CONTROL_FIELDS)}")
            if "stop" in command:
                if command["stop"] is not True:
                    raise SpecError('container.stop: expected {"stop": true}')
                self.stop()
            elif "add" in command:
                self.add(parse_components(command["add"], "add"))
            else:
                self.remove(_instances(command["remove"]))
        except (SpecError, MessageError) as exc:
            logs.count_problem(
                self.counters, "rejected_commands", log, "%s: refused command: %s", self.name, exc
            )

    def _control_handler(self, key: str) -> Callable[[Any], None]:
        """The handler of control key ``key`` (on zenoh's thread): a command for the container's
        thread, or one put on another key refused (``net.address``), counted and logged."""
        key_tag = tag(key)

        def take(sample: Any) -> None:
            if is_misaddressed(sample, key_tag):
                logs.count_problem(
                    self.counters,
                    "misaddressed",
                    log,
                    "%s: refused a command put on another key than %s",
                    self.name,
                    key,
                )
                return
            self._events.put(("control", sample.payload.to_bytes()))

        return take

    def _guarded(self, handler: Any) -> Any:
        return logs.guarded(handler, self.counters, log, self.name)

    # -- status and life cycle ----------------------------------------------------------------

    def status(self) -> dict[str, Any]:
        with self._lock:
            entries = dict(self.components)
        return {
            "container": self.name,
            "pid": os.getpid(),
            "incarnation": self.incarnation,
            "components": {
                instance: {
                    "service": entry.worker.spec.service,
                    "incarnation": entry.worker.incarnation,
                    "restarts": entry.restarts,
                    "spec": entry.worker.spec.as_dict(),
                }
                for instance, entry in entries.items()
            },
            "wires": len(
                GroupSpec(self.name, tuple(e.worker.spec for e in entries.values())).wires
            ),
            "counters": dict(self.counters),
        }

    def _reply(self, query: Any) -> None:
        with query:
            query.reply(self.keys.status(self.name), json.dumps(self.status()), encoding=JSON)

    def stop(self) -> None:
        self._stop.set()
        self._events.put(("wake", None))

    def run(self) -> None:
        """Take commands, rebind, look after the components, until :meth:`stop`; then end
        every component and undeclare."""
        handle = self._guarded(self._handle)
        try:
            while not self._stop.is_set():
                try:
                    handle(*self._events.get(timeout=LOOP_S))
                    while not self._events.empty():
                        handle(*self._events.get_nowait())
                except queue.Empty:
                    pass
                self._guarded(self._look_after)()
        finally:
            self._stop.set()
            self._token.undeclare()
            for control in self._controls:
                control.undeclare()
            self.remove(list(self.components))
            self._left.undeclare()
            self._status.undeclare()
            self.scheduler.stop()
            self.scheduler.join(timeout=JOIN_S)

    def _handle(self, kind: str, event: Any) -> None:
        if kind == "control":
            self._apply_control(event)
        elif kind == "moved":
            self._rebind(event)


def _instances(raw: Any) -> list[str]:
    """The instance names of a remove command."""
    if not isinstance(raw, list):
        raise SpecError("remove: expected a list of instance names")
    names = []
    for index, name in enumerate(raw):
        try:
            names.append(validate_key_chunks(name, single_chunk=True))
        except (ValueError, TypeError) as exc:
            raise SpecError(f"remove[{index}]: {exc}") from None
    return names


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m ubitrack_agent.services.container",
        description="Run many pattern instances in one process (a container), wired in the "
        "process where they read each other, over zenoh elsewhere.",
    )
    parser.add_argument("--name", help="the container's name (default: the group's)")
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--group", help="the group (its components) as JSON text")
    source.add_argument("--group-file", help="a file holding the group")
    logs.add_log_level_argument(parser)
    config.add_arguments(parser)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logs.configure(args.log_level)
    try:
        text = args.group
        if args.group_file is not None:
            with open(args.group_file, encoding="utf-8") as file:
                text = file.read()
        if text is None and args.name is None:
            raise SpecError("give --name, --group or --group-file")
        group = parse_group(text) if text is not None else GroupSpec(args.name)
        if args.name is not None and args.name != group.container:
            raise SpecError(f"--name {args.name!r} is not the group's {group.container!r}")
        for spec in group.components:
            check_spec(spec)
        settings = config.from_arguments(args, role="member")
    except (OSError, SpecError, config.ConfigError) as exc:
        print(f"container: {exc}", file=sys.stderr)
        return 2
    from ubitrack_agent.net.session import open_session

    keys = KeySpace(settings.key_prefix)
    with open_session(settings) as session:
        run_container(session, keys, group, Clock.of(settings))
    return 0


def run_container(
    session: Any, keys: KeySpace, group: GroupSpec, clock: Clock, parent: Parent | None = None
) -> None:
    """Run ``group``'s container on ``session`` until it is stopped (a stop command, SIGTERM or
    SIGINT); ``parent``: the host manager that started the process (a pool member's). The
    objects of the process's start-up are left out of the garbage collector's work first
    (``services.heap``)."""
    settle_collector()
    container = Container(session, keys, group.container, clock, group.components, parent)
    on_termination(container.stop)
    started = time.monotonic()
    log.info("%s: %d components", group.container, len(group.components))
    container.run()
    log.info("%s: ended after %.0f s", group.container, time.monotonic() - started)


if __name__ == "__main__":
    sys.exit(main())
