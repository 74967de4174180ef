"""The host manager protocol (``docs/protocol.md``): requests, replies and exit reports on the
``<root>/host/<name>`` keys, defined once for both ends (the agent and
``ubitrack_agent.services.host_manager``).

A request is one JSON object, the payload of a ``get`` on ``<root>/host/<name>/request``::

    {"op": "start", "spec": {<component specification, ubitrack_agent.net.spec>}}
    {"op": "start_group", "group": {<group: a container and its components>}}
    {"op": "stop", "instance": "<instance>"}
    {"op": "status"}

A ``start_group`` runs the group's components in the container it names
(``ubitrack_agent.services.container``, one process hosting many components): started with them if
it does not run, else they are added to the running process (no process start). Starting N
components on a host is one request. A stop of a component in a container removes it from there; the
container ends with its last component.

Success is an ordinary reply holding a JSON object (:class:`Started` for a start,
:class:`StartedGroup` for a start_group; see the host manager for stop and status); a refusal
is an error reply (zenoh ``reply_err``) holding ``{"error": "<type>", "reason": "<text>"}``,
the type one of :data:`ERRORS`. A host manager reports a worker that ended without being asked
by putting an :class:`Exited` on ``<root>/host/<name>/exited``.

Everything here is pure and total over its input: malformed bytes raise :class:`ProtocolError`
(a ``ValueError``) naming the field, whatever they hold.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from dataclasses import field as dataclass_field
from typing import Any

from ubitrack_agent.core.names import check_label
from ubitrack_agent.net.clock import ClockEstimate, ClockRejection, parse_clock_status
from ubitrack_agent.net.json_messages import MessageError, field, load_object
from ubitrack_agent.net.keys import validate_key_chunks
from ubitrack_agent.net.spec import ComponentSpec, GroupSpec, SpecError, parse_group, parse_spec

MAX_MESSAGE_BYTES = 256 * 1024
"""Largest request or report accepted; a specification takes a few kilobytes (the agent splits
a larger start_group into several requests)."""

ERRORS = (
    "malformed_request",
    "oversized_request",
    "refused_spec",
    "failed_spawn",
    "over_capacity",
    "internal_error",
)
"""Error types of a refused request: not a well-formed request (bad UTF-8 or JSON, nesting too
deep, wrong fields or types); larger than :data:`MAX_MESSAGE_BYTES`; a specification that is
malformed or names no registered service; the worker process could not be started; the host
manager already runs as many workers as its capacity; a fault of the host manager itself
(logged there)."""

EXIT_REASONS = ("exited", "released", "restored")
"""Why an instance ended without its host manager being asked: its process exited, or a stop
command from elsewhere released the process (it went back to the pool, or left its
container); or its container died and the host manager started it again with the instance
(``restored``: the report's ``pid`` is the new process's, and the instance runs there with the
specification it was started with, under the same run: the agent sends its current wiring)."""

STOP_COMMAND = json.dumps({"stop": True})
"""The control command that ends a worker (``ubitrack_agent.services.worker``), put on its
control key."""


class ProtocolError(ValueError):
    """A message that breaks the protocol; ``error`` is its type (one of :data:`ERRORS`)."""

    def __init__(self, error: str, reason: str) -> None:
        super().__init__(f"{error}: {reason}")
        self.error = error
        self.reason = reason

    def to_json(self) -> str:
        """The payload of the error reply."""
        return json.dumps({"error": self.error, "reason": self.reason})

    @classmethod
    def parse(cls, payload: bytes) -> ProtocolError:
        """The refusal carried by an error reply."""
        data = _json_object(payload)
        error = _field(data, "error", str)
        if error not in ERRORS:
            raise ProtocolError("malformed_request", f"error: unknown type {error!r}")
        return cls(error, _field(data, "reason", str))


@dataclass(frozen=True)
class Start:
    """Run ``spec`` on the host."""

    spec: ComponentSpec


@dataclass(frozen=True)
class StartGroup:
    """Run ``group``'s components in its container (started with them, or added to it)."""

    group: GroupSpec


@dataclass(frozen=True)
class Stop:
    """Stop ``instance``: its stop command is put on its control key, its process released."""

    instance: str


@dataclass(frozen=True)
class Status:
    """Answer the host manager's state."""


Request = Start | StartGroup | Stop | Status


def encode_request(request: Request) -> str:
    """The JSON payload of ``request``."""
    if isinstance(request, Start):
        return json.dumps({"op": "start", "spec": request.spec.as_dict()})
    if isinstance(request, StartGroup):
        return json.dumps({"op": "start_group", "group": request.group.as_dict()})
    if isinstance(request, Stop):
        return json.dumps({"op": "stop", "instance": request.instance})
    return json.dumps({"op": "status"})


def parse_request(payload: bytes | None) -> Request:
    """The request in ``payload``; :class:`ProtocolError` if it is not one. The specification
    of a start is checked for form only (``ubitrack_agent.services.spec.check_spec`` checks the
    service)."""
    data = _json_object(payload)
    op = data.get("op")
    fields = {
        "start": {"op", "spec"},
        "start_group": {"op", "group"},
        "stop": {"op", "instance"},
        "status": {"op"},
    }
    if not isinstance(op, str) or op not in fields:
        raise ProtocolError("malformed_request", f"op: expected one of {sorted(fields)}")
    if set(data) != fields[op]:
        raise ProtocolError("malformed_request", f"{op}: expected exactly {sorted(fields[op])}")
    if op == "start":
        spec = data["spec"]
        if not isinstance(spec, dict):
            raise ProtocolError("malformed_request", "spec: expected an object")
        try:
            return Start(parse_spec(spec))
        except SpecError as exc:
            raise ProtocolError("refused_spec", str(exc)) from None
    if op == "start_group":
        group = data["group"]
        if not isinstance(group, dict):
            raise ProtocolError("malformed_request", "group: expected an object")
        try:
            return StartGroup(parse_group(group))
        except SpecError as exc:
            raise ProtocolError("refused_spec", str(exc)) from None
    if op == "stop":
        return Stop(_name(data, "instance"))
    return Status()


@dataclass(frozen=True)
class Started:
    """The reply to a start: ``run`` names this start of ``instance`` on the host (exit reports
    carry it); ``reused`` if the instance was already running there with the same
    specification (a repeated request starts nothing)."""

    instance: str
    run: str
    pid: int
    reused: bool

    def to_json(self) -> str:
        return json.dumps(asdict(self))

    @classmethod
    def parse(cls, payload: bytes) -> Started:
        data = _json_object(payload)
        reused = data.get("reused")
        if not isinstance(reused, bool):
            raise ProtocolError("malformed_request", "reused: expected true or false")
        return cls(_name(data, "instance"), _name(data, "run"), _field(data, "pid", int), reused)


@dataclass(frozen=True)
class StartedGroup:
    """The reply to a start_group: the container's process (``pid``) and each component's
    :class:`Started` (its pid the container's)."""

    container: str
    pid: int
    started: tuple[Started, ...]

    def to_json(self) -> str:
        return json.dumps(
            {
                "container": self.container,
                "pid": self.pid,
                "started": [asdict(started) for started in self.started],
            }
        )

    @classmethod
    def parse(cls, payload: bytes) -> StartedGroup:
        data = _json_object(payload)
        entries = _field(data, "started", list)
        started = []
        for entry in entries:
            if not isinstance(entry, dict):
                raise ProtocolError("malformed_request", "started: expected objects")
            started.append(Started.parse(json.dumps(entry).encode()))
        return cls(_name(data, "container"), _field(data, "pid", int), tuple(started))


@dataclass(frozen=True)
class Exited:
    """An instance that ended on ``<root>/host/<name>/exited`` without its host manager being
    asked: ``reason`` is one of :data:`EXIT_REASONS`; ``returncode`` is None when released."""

    instance: str
    run: str
    pid: int
    returncode: int | None
    reason: str

    def to_json(self) -> str:
        return json.dumps(asdict(self))

    @classmethod
    def parse(cls, payload: bytes) -> Exited:
        data = _json_object(payload)
        returncode = data.get("returncode")
        if returncode is not None and type(returncode) is not int:
            raise ProtocolError("malformed_request", "returncode: expected an integer or null")
        reason = data.get("reason")
        if reason not in EXIT_REASONS:
            raise ProtocolError("malformed_request", f"reason: expected one of {EXIT_REASONS}")
        return cls(
            _name(data, "instance"),
            _name(data, "run"),
            _field(data, "pid", int),
            returncode,
            reason,
        )


MAX_LABELS = 32
"""Labels a host manager may carry at most."""
MAX_CAPACITY = 10_000
"""Largest capacity (workers at most) a host manager may announce."""
DEFAULT_CAPACITY = 1000
"""Components a host manager runs at most unless told: they share its containers (a
component in a container holds about 1 MB, a container about 100 MB; issue 28)."""
MAX_CORES = 1024
"""Most containers a host manager may announce it runs its shared components in."""


@dataclass(frozen=True)
class HostInfo:
    """What a host manager says of itself in its status reply, and all placement and clock
    correction use (``agent.placement``, ``agent.clocks``): its ``labels`` (``camera``,
    ``gpu``, ``hmd``...), how many components it runs at most (``capacity``), how many
    containers its components share (``cores``: one per CPU core it may use, the agent's
    grouping rule, ``agent.placement.group_containers``), whether each of its components runs
    alone in a container (``isolating``: untrusted or crash-prone code), its CPU load per core
    (``cpu_load``: the one-minute load average over the cores; 1.0 is every core busy), and its
    clock's offset to the agent's (``clock``, None until measured)."""

    name: str
    labels: frozenset[str] = frozenset()
    capacity: int = DEFAULT_CAPACITY
    cpu_load: float = 0.0
    clock: ClockEstimate | None = None
    runs: Mapping[str, tuple[str, int, str | None]] = dataclass_field(
        default_factory=dict, compare=False
    )
    """The instances it runs, with their run, pid and container (None: a worker process of
    its own; its status's ``instances``): how the agent finds where a component runs that it
    has no placement for (adopted, or left alone by a move that failed half-way)."""
    cores: int = 1
    isolating: bool = False

    def as_dict(self) -> dict[str, Any]:
        """The fields as they appear in the status reply (the clock as of now: age 0)."""
        return {
            "name": self.name,
            "labels": sorted(self.labels),
            "capacity": self.capacity,
            "cores": self.cores,
            "isolating": self.isolating,
            "cpu_load": self.cpu_load,
            "clock": None if self.clock is None else self.clock.as_status(0.0),
        }

    @classmethod
    def parse(cls, payload: bytes) -> HostInfo:
        """The host information in a status reply (other fields are ignored; a missing
        ``clock`` is None, missing ``cores`` 1, missing ``isolating`` false);
        :class:`ProtocolError` naming the field if it is malformed."""
        data = _json_object(payload)
        labels = _field(data, "labels", list)
        if len(labels) > MAX_LABELS:
            raise ProtocolError("malformed_request", f"labels: more than {MAX_LABELS}")
        names = frozenset(_label(label) for label in labels)
        capacity = _field(data, "capacity", int)
        if not 1 <= capacity <= MAX_CAPACITY:
            raise ProtocolError("malformed_request", f"capacity: expected 1 to {MAX_CAPACITY}")
        cpu_load = data.get("cpu_load")
        if type(cpu_load) not in (int, float) or not 0 <= cpu_load < math.inf:
            raise ProtocolError("malformed_request", "cpu_load: expected a finite number >= 0")
        clock = parse_clock_status(data.get("clock"))
        if isinstance(clock, ClockRejection):
            raise ProtocolError("malformed_request", clock.reason)
        cores = data.get("cores", 1)
        if type(cores) is not int or not 1 <= cores <= MAX_CORES:
            raise ProtocolError("malformed_request", f"cores: expected 1 to {MAX_CORES}")
        isolating = data.get("isolating", False)
        if not isinstance(isolating, bool):
            raise ProtocolError("malformed_request", "isolating: expected true or false")
        runs = _runs(data.get("instances", {}))
        return cls(
            _name(data, "name"), names, capacity, float(cpu_load), clock, runs, cores, isolating
        )


def _runs(value: Any) -> dict[str, tuple[str, int, str | None]]:
    """The ``instances`` of a status reply: instance -> (run, pid, container or None)."""
    if not isinstance(value, dict):
        raise ProtocolError("malformed_request", "instances: expected an object")
    runs = {}
    for instance, entry in value.items():
        if not isinstance(entry, dict):
            raise ProtocolError("malformed_request", "instances: expected objects")
        try:
            name = validate_key_chunks(instance, single_chunk=True)
        except ValueError as exc:
            raise ProtocolError("malformed_request", f"instances: {exc}") from None
        container = entry.get("container")
        runs[name] = (
            _name(entry, "run"),
            _field(entry, "pid", int),
            None if container is None else _name(entry, "container"),
        )
    return runs


def _label(value: Any) -> str:
    try:
        return check_label(value)
    except ValueError as exc:
        raise ProtocolError("malformed_request", f"labels: {exc}") from None


def _json_object(payload: bytes | None) -> dict[str, Any]:
    try:
        return load_object(payload, MAX_MESSAGE_BYTES)
    except MessageError as exc:
        raise ProtocolError(exc.error, exc.reason) from None


def _field(data: Mapping[str, Any], name: str, kind: type) -> Any:
    try:
        return field(data, name, kind)
    except MessageError as exc:
        raise ProtocolError(exc.error, exc.reason) from None


def _name(data: Mapping[str, Any], name: str) -> str:
    value = _field(data, name, str)
    try:
        return validate_key_chunks(value, single_chunk=True)
    except ValueError as exc:
        raise ProtocolError("malformed_request", f"{name}: {exc}") from None
