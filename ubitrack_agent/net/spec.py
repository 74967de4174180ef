"""The component specification: what the agent hands a host manager, a worker process is
started with, and a running worker is rewired by.

JSON form::

    {"instance": "concat-1", "service": "concatenation", "parameters": {},
      "inputs": [{"port": "AB", "key": "ubitrack/default/data/art/ART_WT", "static": true},
                {"port": "BC", "key": "ubitrack/default/data/art/ART_HT", "trigger": true,
                 "clock_offset_ns": -300000000}],
     "outputs": {"AC": "ubitrack/default/data/concat-1/AC"},
     "relations": {"AC": ["ubitrack/default/relation/C/A/6D/dynamic"]},
     "expansion": "none", "tolerance_ms": 20}

``relations`` lists, per output port, the stable relation keys (``docs/protocol.md``) the output
is also published on, for the applications that asked for it. ``trigger`` marks the push inputs
whose samples cause a computation; ``static`` inputs answer their latest value. Every
binding names an input port of the service: each step of a pattern is a component of its own,
and the components of one derivation on a host run in one container (:class:`GroupSpec`),
where they hand each other their outputs as objects.
``clock_offset_ns`` (an integer within a day either way, default 0, omitted when 0) is added
to the timestamp of every sample arriving on the input before it is used: the agent sets it to
the offset of the sensor host's clock to the agent's (``agent.clocks``) when a component reads
inputs from hosts whose clocks differ by more than its tolerance. ``expansion``
(``none``, ``space`` or ``time``, default ``none``) says how the pattern's correspondence is
expanded (paper section 3.3): under ``space`` each correspondence port takes several bindings,
in correspondence order; under ``time`` one, and the worker accumulates samples (options in
``time_expansion``, see :func:`parse_time_expansion`).

:func:`parse_spec` checks the form of every field and raises :class:`SpecError` naming the
field; whether the service is registered and its ports match is checked where services are
known, by ``ubitrack_agent.services.spec.check_spec`` (the agent never imports a service).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from ubitrack_agent.net.config import MAX_CLOCK_OFFSET_NS
from ubitrack_agent.net.json_messages import MessageError, load_object
from ubitrack_agent.net.keys import validate_key_chunks

MAX_SPEC_BYTES = 256 * 1024
"""Largest specification read from text (a specification takes a few kilobytes)."""

MAX_REQUIRED = 1000
"""At most this many names or keys in a list of a specification (``required_providers``,
``required_edges``)."""
DEFAULT_TOLERANCE_MS = 5.0
"""How far from a trigger's time the nearest sample of an input may be when there is no
sample on each side to interpolate between (a moving target at 1 m/s moves 5 mm in 5 ms)."""
DEFAULT_WAIT_MS = 50.0
"""The longest a trigger waits for the other inputs' next samples (see
ubitrack_agent.services.triggers)."""
HAND_OVER_HOLD_S = 1.0
"""How long the agent keeps a replaced flow running after the new one is alive (``agent.runtime``,
make before break), for its producer to hand the relation key over
(``ubitrack_agent.services.handover``)."""
STANDBY_S = 10.0
"""How long the agent keeps the old derivation of a relation that lost a sensor running beside
the new one (``agent.standby``): long enough for a tracker restarted or a body occluded for a
few seconds."""
EXPANSIONS = ("none", "space", "time")
TIME_EXPANSION_OPTIONS = ("min_motion", "min_rotation_deg", "max_samples")
"""Options of a time expansion (``ubitrack_agent.services.expansion``): least change of a position
or translation (m, or px for 2D), least change of a rotation (degrees), the history's bound."""


class SpecError(ValueError):
    """A component specification is invalid."""


@dataclass(frozen=True)
class InputBinding:
    """One input edge bound to a port: the data key it arrives on and how to sample it."""

    port: str
    key: str
    trigger: bool = False
    static: bool = False
    clock_offset_ns: int = 0
    """Added to each sample's timestamp: from its host's clock to the agent's (``net.clock``)."""
    from_worker: bool = False
    """The key is another worker's output: its samples, computed by this package's maths, are
    validated at level ``WORKER`` (``core.measurements``: shapes, finiteness, positive
    semi-definite covariances), not ``FULL`` as a provider's are. A trust boundary only where
    zenoh's access control lets only workers publish on workers' keys (``docs/security.md``);
    without it, a hostile publisher's sample is still refused if it is malformed or could
    break the maths, and the unchecked properties only change the value it carries, which a
    publisher can do anyway."""
    fixed_error: bool = False
    """A static input whose error is the same in every sample: a value given once (a
    calibration, a survey: a static edge announced without a rate) or a static output a worker
    estimated from such values or over time. Its covariance is marked static
    (``ErrorPose.static_covariance``), for a fusion downstream to consider. Not so a static edge
    measured again at a rate (a tracker's static body): each sample has an error of its own."""

    def as_dict(self) -> dict[str, Any]:
        """The JSON-ready form :func:`parse_bindings` reads (``clock_offset_ns``,
        ``from_worker`` and ``fixed_error`` only when set)."""
        data: dict[str, Any] = {
            "port": self.port,
            "key": self.key,
            "trigger": self.trigger,
            "static": self.static,
        }
        if self.clock_offset_ns:
            data["clock_offset_ns"] = self.clock_offset_ns
        if self.from_worker:
            data["from_worker"] = True
        if self.fixed_error:
            data["fixed_error"] = True
        return data


@dataclass(frozen=True)
class ComponentSpec:
    """Everything a worker needs to run one pattern instance."""

    instance: str
    service: str
    inputs: tuple[InputBinding, ...]
    outputs: dict[str, str]
    relations: dict[str, tuple[str, ...]] = field(default_factory=dict)
    parameters: dict[str, Any] = field(default_factory=dict)
    expansion: str = "none"
    time_expansion: dict[str, float] = field(default_factory=dict)
    tolerance_ms: float = DEFAULT_TOLERANCE_MS
    wait_ms: float = DEFAULT_WAIT_MS
    required_providers: tuple[str, ...] = ()
    """The providers without whose samples this component computes nothing new
    (``agent.materialise.required_inputs``): a producer of a relation key gives the key up
    as soon as one of them leaves (``services.handover``, rule 7)."""
    required_edges: tuple[str, ...] = ()
    """The data keys of the measured edges without whose samples this component computes
    nothing new (``agent.materialise.required_inputs``): a producer of a relation key gives the
    key up as soon as one of them stops delivering (its provider's token on the key withdrawn,
    ``io.flowing``; ``services.handover``, rule 7)."""

    @property
    def tolerance_ns(self) -> int:
        return int(self.tolerance_ms * 1e6)

    def as_dict(self) -> dict[str, Any]:
        """The JSON-ready form :func:`parse_spec` reads."""
        return {
            "instance": self.instance,
            "service": self.service,
            "parameters": self.parameters,
            "inputs": [binding.as_dict() for binding in self.inputs],
            "outputs": self.outputs,
            "relations": {port: list(keys) for port, keys in self.relations.items()},
            "expansion": self.expansion,
            "time_expansion": self.time_expansion,
            "tolerance_ms": self.tolerance_ms,
            "wait_ms": self.wait_ms,
            "required_providers": list(self.required_providers),
            "required_edges": list(self.required_edges),
        }

    def to_json(self) -> str:
        return json.dumps(self.as_dict())


def _require(data: Mapping[str, Any], name: str, kind: type, where: str) -> Any:
    if name not in data:
        raise SpecError(f"{where}.{name}: missing")
    value = data[name]
    if not isinstance(value, kind) or isinstance(value, bool):
        raise SpecError(f"{where}.{name}: expected {kind.__name__}")
    return value


def _name(data: Mapping[str, Any], name: str, where: str) -> str:
    """Field ``name`` of ``data``: one key chunk (an instance's, a service's name)."""
    value = _require(data, name, str, where)
    try:
        return validate_key_chunks(value, single_chunk=True)
    except ValueError as exc:
        raise SpecError(f"{where}.{name}: {exc}") from None


def _listed(raw: Any, where: str, single_chunk: bool) -> tuple[str, ...]:
    """A list of at most :data:`MAX_REQUIRED` literal keys, each one chunk if ``single_chunk``
    (providers' ids: names), else any number (measured edges' data keys)."""
    what = "names" if single_chunk else "keys"
    if not isinstance(raw, list) or len(raw) > MAX_REQUIRED:
        raise SpecError(f"{where}: expected a list of at most {MAX_REQUIRED} {what}")
    listed = []
    for index, value in enumerate(raw):
        if not isinstance(value, str):
            raise SpecError(f"{where}[{index}]: expected a string")
        try:
            listed.append(validate_key_chunks(value, single_chunk=single_chunk))
        except ValueError as exc:
            raise SpecError(f"{where}[{index}]: {exc}") from None
    return tuple(listed)


def _key(value: Any, where: str) -> str:
    try:
        return validate_key_chunks(value)
    except ValueError as exc:
        raise SpecError(f"{where}: {exc}") from None


BINDING_FIELDS = frozenset(
    {"port", "key", "trigger", "static", "clock_offset_ns", "from_worker", "fixed_error"}
)
"""The fields of an input binding on the wire (:meth:`InputBinding.as_dict`)."""


def parse_bindings(raw: Any, where: str = "spec.inputs") -> tuple[InputBinding, ...]:
    """The form of a list of input bindings (ports are checked against the service by
    ``ubitrack_agent.services.spec.check_bindings``)."""
    if not isinstance(raw, list):
        raise SpecError(f"{where}: expected a list of bindings")
    bindings = []
    for index, item in enumerate(raw):
        at = f"{where}[{index}]"
        if not isinstance(item, dict):
            raise SpecError(f"{at}: expected an object")
        unknown = sorted(set(item) - BINDING_FIELDS)
        if unknown:
            raise SpecError(f"{at}: unknown fields {unknown}")
        port = _require(item, "port", str, at)
        trigger, static = item.get("trigger", False), item.get("static", False)
        from_worker, fixed_error = item.get("from_worker", False), item.get("fixed_error", False)
        if not all(isinstance(flag, bool) for flag in (trigger, static, from_worker, fixed_error)):
            raise SpecError(
                f"{at}: trigger, static, from_worker and fixed_error must be true or false"
            )
        if fixed_error and not static:
            raise SpecError(f"{at}: fixed_error is for a static input")
        offset = item.get("clock_offset_ns", 0)
        if type(offset) is not int or abs(offset) > MAX_CLOCK_OFFSET_NS:
            raise SpecError(
                f"{at}.clock_offset_ns: expected integer nanoseconds within +-{MAX_CLOCK_OFFSET_NS}"
            )
        key = _key(item.get("key"), f"{at}.key")
        bindings.append(InputBinding(port, key, trigger, static, offset, from_worker, fixed_error))
    if not any(binding.trigger for binding in bindings):
        raise SpecError(f"{where}: no binding is marked trigger")
    return tuple(bindings)


def parse_outputs(raw: Any, where: str = "spec.outputs") -> dict[str, str]:
    """The form of ``{output port: data key}`` (ports are checked against the service by
    ``ubitrack_agent.services.spec.check_outputs``)."""
    if not isinstance(raw, dict):
        raise SpecError(f"{where}: expected an object")
    return {port: _key(key, f"{where}.{port}") for port, key in raw.items()}


def parse_relations(raw: Any, where: str = "spec.relations") -> dict[str, tuple[str, ...]]:
    """The form of ``{output port: [relation key, ...]}``."""
    if not isinstance(raw, dict):
        raise SpecError(f"{where}: expected an object of output port -> list of keys")
    relations = {}
    for port, keys in raw.items():
        if not isinstance(keys, list):
            raise SpecError(f"{where}.{port}: expected a list of keys")
        relations[port] = tuple(_key(key, f"{where}.{port}") for key in keys)
    return relations


def parse_time_expansion(options: Any) -> dict[str, float]:
    """Validate time-expansion options (:data:`TIME_EXPANSION_OPTIONS`)."""
    if not isinstance(options, Mapping):
        raise ValueError("expected an object")
    unknown = sorted(set(options) - set(TIME_EXPANSION_OPTIONS))
    if unknown:
        raise ValueError(f"unknown options {unknown}; known: {list(TIME_EXPANSION_OPTIONS)}")
    for name, value in options.items():
        if isinstance(value, bool) or not isinstance(value, int | float) or not 0 <= value < 1e12:
            raise ValueError(f"{name} must be a number >= 0 and below 1e12")
    if "max_samples" in options and not 1 <= options["max_samples"] <= 100_000:
        raise ValueError("max_samples must be in [1, 100000]")
    return {name: float(value) for name, value in options.items()}


def _milliseconds(data: Mapping[str, Any], name: str, default: float) -> float:
    value = data.get(name, default)
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0 <= value <= 10_000:
        raise SpecError(f"spec.{name}: expected a number of milliseconds in [0, 10000]")
    return float(value)


def _read_object(text: str | bytes | Mapping[str, Any], max_bytes: int, where: str) -> dict:
    """The JSON object in ``text`` (read by :func:`~ubitrack_agent.net.json_messages.load_object`:
    at most ``max_bytes``), or ``text`` itself if already read; :class:`SpecError` otherwise."""
    if isinstance(text, str | bytes):
        raw = text.encode("utf-8", "surrogatepass") if isinstance(text, str) else text
        try:
            return load_object(raw, max_bytes)
        except MessageError as exc:
            raise SpecError(f"{where}: {exc.reason}") from None
    if not isinstance(text, dict):
        raise SpecError(f"{where}: expected a JSON object")
    return text


def parse_spec(text: str | bytes | Mapping[str, Any]) -> ComponentSpec:
    """Parse and validate a specification: JSON text or bytes (from the command line or the
    network, read by :func:`~ubitrack_agent.net.json_messages.load_object`: at most
    :data:`MAX_SPEC_BYTES`, nested at most ``MAX_DEPTH`` deep), or a mapping already read so.
    Raises :class:`SpecError` and nothing else."""
    data = _read_object(text, MAX_SPEC_BYTES, "spec")
    known = {
        "instance",
        "service",
        "parameters",
        "inputs",
        "outputs",
        "relations",
        "expansion",
        "time_expansion",
        "tolerance_ms",
        "wait_ms",
        "required_providers",
        "required_edges",
    }
    unknown = sorted(set(data) - known)
    if unknown:
        raise SpecError(f"spec: unknown fields {unknown}")
    instance = _name(data, "instance", "spec")
    name = _name(data, "service", "spec")
    parameters = data.get("parameters", {})
    if not isinstance(parameters, dict):
        raise SpecError("spec.parameters: expected an object")
    outputs = parse_outputs(_require(data, "outputs", dict, "spec"))
    expansion = data.get("expansion", "none")
    if expansion not in EXPANSIONS:
        raise SpecError(f"spec.expansion: must be one of {EXPANSIONS}, got {expansion!r}")
    time_expansion = data.get("time_expansion", {})
    if expansion != "time" and time_expansion:
        raise SpecError("spec.time_expansion: only for expansion 'time'")
    try:
        time_expansion = parse_time_expansion(time_expansion)
    except ValueError as exc:
        raise SpecError(f"spec.time_expansion: {exc}") from None
    tolerance = _milliseconds(data, "tolerance_ms", DEFAULT_TOLERANCE_MS)
    wait = _milliseconds(data, "wait_ms", DEFAULT_WAIT_MS)
    return ComponentSpec(
        instance=instance,
        service=name,
        inputs=parse_bindings(data.get("inputs")),
        outputs=outputs,
        relations=parse_relations(data.get("relations", {})),
        parameters=dict(parameters),
        expansion=expansion,
        time_expansion=time_expansion,
        tolerance_ms=tolerance,
        wait_ms=wait,
        required_providers=_listed(
            data.get("required_providers", []), "spec.required_providers", single_chunk=True
        ),
        required_edges=_listed(
            data.get("required_edges", []), "spec.required_edges", single_chunk=False
        ),
    )


MAX_GROUP_COMPONENTS = 1000
"""Most component specifications one group (one container) holds."""
MAX_GROUP_BYTES = 4 * 1024 * 1024
"""Largest group read from text (a thousand specifications of a few kilobytes)."""


@dataclass(frozen=True)
class LocalWire:
    """A wire inside a container: output ``port`` of ``producer`` read by input ``index`` of
    ``reader`` (its binding's key is the producer's output key), handed over as the
    measurement object, with no encoding and no zenoh (``ubitrack_agent.services.local_wires``)."""

    producer: str
    port: str
    reader: str
    index: int


@dataclass(frozen=True)
class GroupSpec:
    """The components one container (a worker process hosting many component instances,
    ``ubitrack_agent.services.container``) runs: their specifications, named by the container.

    JSON form: ``{"container": "<name>", "components": [<specification>, ...]}``.
    The local wires are not written out: they follow from the keys (:attr:`wires`), so a group
    cannot name a wire that its specifications contradict. Instance names are unique in a
    group. Two components may publish on one data key, as two processes may (the agent names
    each output after its component, so it never asks for it); a reader of the key in the
    container then takes the values of both, as it would over zenoh."""

    container: str
    components: tuple[ComponentSpec, ...] = ()

    @property
    def wires(self) -> tuple[LocalWire, ...]:
        """Every input of a component reading another component's output in this group, in
        component and binding order. O(bindings + outputs)."""
        producers = {
            key: (spec.instance, port)
            for spec in self.components
            for port, key in spec.outputs.items()
        }
        return tuple(
            LocalWire(*producers[binding.key], spec.instance, index)
            for spec in self.components
            for index, binding in enumerate(spec.inputs)
            if binding.key in producers
        )

    def as_dict(self) -> dict[str, Any]:
        """The JSON-ready form :func:`parse_group` reads."""
        return {
            "container": self.container,
            "components": [spec.as_dict() for spec in self.components],
        }

    def to_json(self) -> str:
        return json.dumps(self.as_dict())


def check_group_members(components: tuple[ComponentSpec, ...], where: str = "group") -> None:
    """:class:`SpecError` if two of ``components`` share an instance name, or there are more
    than :data:`MAX_GROUP_COMPONENTS`."""
    if len(components) > MAX_GROUP_COMPONENTS:
        raise SpecError(f"{where}.components: more than {MAX_GROUP_COMPONENTS}")
    instances: set[str] = set()
    for index, spec in enumerate(components):
        if spec.instance in instances:
            raise SpecError(f"{where}.components[{index}].instance: {spec.instance!r} twice")
        instances.add(spec.instance)


def parse_group(text: str | bytes | Mapping[str, Any]) -> GroupSpec:
    """Parse and validate a group: JSON text or bytes (at most :data:`MAX_GROUP_BYTES`), or a
    mapping already read. Raises :class:`SpecError` naming the field, and nothing else."""
    data = _read_object(text, MAX_GROUP_BYTES, "group")
    unknown = sorted(set(data) - {"container", "components"})
    if unknown:
        raise SpecError(f"group: unknown fields {unknown}")
    container = _name(data, "container", "group")
    components = parse_components(data.get("components", []), "group.components")
    return GroupSpec(container, components)


def parse_components(raw: Any, where: str) -> tuple[ComponentSpec, ...]:
    """A list of specifications (:func:`parse_spec` each), checked as members of one group
    (:func:`check_group_members`)."""
    if not isinstance(raw, list):
        raise SpecError(f"{where}: expected a list of specifications")
    if len(raw) > MAX_GROUP_COMPONENTS:
        raise SpecError(f"{where}: more than {MAX_GROUP_COMPONENTS}")
    components = []
    for index, item in enumerate(raw):
        if not isinstance(item, dict):
            raise SpecError(f"{where}[{index}]: expected an object")
        try:
            components.append(parse_spec(item))
        except SpecError as exc:
            raise SpecError(f"{where}[{index}]: {exc}") from None
    specs = tuple(components)
    check_group_members(specs, where.rsplit(".", 1)[0])
    return specs


def parse_assignment(text: str | bytes | Mapping[str, Any]) -> ComponentSpec | GroupSpec:
    """What a pool member is given to run (``ubitrack_agent.services.worker.Pool``): a group (an
    object with a ``container`` field, :func:`parse_group`) or one specification
    (:func:`parse_spec`). Raises :class:`SpecError` and nothing else."""
    data = _read_object(text, MAX_GROUP_BYTES, "assignment")
    return parse_group(data) if "container" in data else parse_spec(data)
