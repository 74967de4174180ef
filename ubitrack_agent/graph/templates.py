"""Template service descriptions: declarative spatial relationship patterns (sections 3.2, 5.2.1).

A template is one YAML file in ``templates/`` describing one pattern ``P``: its roles (the node
set ``V_P``), input edges ``I_P`` with predicates on type / static / mode, output edges ``O_P``
with their attributes, an optional correspondence ``C_P = (C_P, M_P)`` with the allowed
expansions (section 3.3), the registered service that runs it, its parameters and the constants
of the planner's cost model. Types may be a type variable (``$T``) ranging over a declared
domain, so one template covers e.g. 6D and 3D concatenation. A template never names Python
code: ``service`` is a registry name, resolved by the services registry at run time.

The pattern names are those of the loaded templates: nothing here lists them. A template's
``signature`` tells the planner how to recognise one computation derived in several ways
(section 5.1), the only thing it needs to know about particular patterns.
"""

from __future__ import annotations

import importlib.resources
import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import Any

import yaml

from ubitrack_agent.core.names import LABEL_PATTERN
from ubitrack_agent.graph.srg import EDGE_TYPES, MODES

EXPANSIONS: frozenset[str] = frozenset({"space", "time"})
COST_RULES: frozenset[str] = frozenset({"sum", "fusion", "pooled"})
SIGNATURES: frozenset[str] = frozenset({"step", "inverse", "chain"})
"""How the planner identifies a pattern's outputs (:attr:`Template.signature`)."""
ISOLATIONS: frozenset[str] = frozenset({"shared", "own"})
"""Whether the pattern's instances share a container with others (:attr:`Template.isolation`)."""


_SERVICE_NAME = re.compile(r"^[a-z][a-z0-9_]*$")
_PATTERN_NAME = re.compile(r"^[A-Z][A-Za-z0-9]*$")
_ROLE_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
_MULTIPLICITY = re.compile(r"^\s*(\d+)\s*(?:\.\.\s*(\d+|\*)\s*)?$")


class TemplateError(ValueError):
    """A template file is invalid; the message names the file, the entry and the field."""


@dataclass(frozen=True)
class Multiplicity:
    """The acceptable numbers ``M_P`` of corresponding measurements, ``lo..hi`` (None: no limit)."""

    lo: int
    hi: int | None

    def __contains__(self, m: object) -> bool:
        return isinstance(m, int) and m >= self.lo and (self.hi is None or m <= self.hi)

    def __str__(self) -> str:
        return f"{self.lo}..{'*' if self.hi is None else self.hi}"


@dataclass(frozen=True)
class InputSpec:
    """An input edge of the pattern: roles, type (literal or ``$VAR``) and predicates on static,
    mode and measured (``None`` accepts anything); ``not_from`` lists patterns whose outputs the
    input must not be (e.g. no inversion of an inversion, section 5.1)."""

    name: str
    source: str
    target: str
    type: str
    static: bool | None = None
    mode: str | None = None
    measured: bool | None = None
    not_from: frozenset[str] = frozenset()

    @cached_property
    def type_var(self) -> str | None:
        """The type variable the input's type names (``$T``: ``T``), ``None`` for a literal type."""
        return self.type[1:] if self.type.startswith("$") else None

    @cached_property
    def has_predicates(self) -> bool:
        """Whether the input asks anything of an edge besides its type (static, mode,
        measured, not_from)."""
        return (
            self.static is not None
            or self.mode is not None
            or self.measured is not None
            or bool(self.not_from)
        )


@dataclass(frozen=True)
class OutputSpec:
    """An output edge. ``static``: ``"inherit"`` (static iff all inputs are), True or False;
    ``mode``: ``"inherit"`` (push iff some input pushes), ``"push"`` or ``"pull"``."""

    name: str
    source: str
    target: str
    type: str
    static: bool | str = "inherit"
    mode: str = "inherit"


@dataclass(frozen=True)
class Correspondence:
    """Correspondence set (section 3.3): the input edges that are related, their multiplicity,
    the allowed expansions and the roles duplicated by a space expansion (the node set ``F_P``).

    ``independent`` requires the copies of a space expansion to have pairwise disjoint sources
    (fusion); otherwise each copy must only add information the others lack (section 5.1).
    """

    edges: tuple[str, ...]
    multiplicity: Multiplicity
    expansions: frozenset[str]
    expand_roles: tuple[str, ...] = ()
    independent: bool = False


@dataclass(frozen=True)
class CostSpec:
    """Constants of the cost model for this pattern (see ``docs/planner.md``).

    ``rule`` combines input variances: ``sum`` (first-order propagation), ``fusion`` (inverse
    variance weighting) or ``pooled`` (non-corresponding inputs summed, corresponding copies
    averaged and scaled by ``lo / m``). ``gain`` scales the result, ``time_gain`` scales a time
    expansion's result further (integration over many samples), ``latency`` is added (s).
    """

    rule: str = "sum"
    gain: float = 1.0
    time_gain: float = 1.0
    latency: float = 0.0


@dataclass(frozen=True)
class Template:
    """One validated template service description.

    ``host_labels`` are labels a host must have to run the service (``agent.placement``): a
    service needing a GPU or a camera's local bus says so.

    ``isolation`` says where an instance runs on its host: ``shared`` (the default) in a
    container with the other components of its derivation, ``own`` alone in a container of its
    own (``agent.placement.group_containers``): a real camera's adapter, OpenCV-heavy or
    untrusted code, whose crash or stall then takes down no other component.

    ``signature`` says how the planner identifies the computation an output stands for, to drop
    derivations that differ only in how they were put together (section 5.1): ``step`` (its own
    step on its inputs), ``inverse`` (its single input read the other way round: the same
    computation, e.g. inversion) or ``chain`` (the chain of its inputs' computations whatever the
    bracketing, e.g. concatenation; the planner also builds chains only towards the query).
    """

    name: str
    pattern: str
    service: str
    description: str
    roles: tuple[str, ...]
    type_vars: Mapping[str, tuple[str, ...]]
    inputs: tuple[InputSpec, ...]
    outputs: tuple[OutputSpec, ...]
    correspondence: Correspondence | None
    cost: CostSpec
    parameters: Mapping[str, Any] = field(default_factory=dict)
    signature: str = "step"
    host_labels: frozenset[str] = frozenset()
    isolation: str = "shared"

    @cached_property
    def time_only(self) -> bool:
        """True if the pattern is only ever applied expanded in time (its outputs are static)."""
        return self.correspondence is not None and self.correspondence.expansions == {"time"}

    @cached_property
    def in_correspondence(self) -> tuple[bool, ...]:
        """For each input, in order, whether it is a correspondence edge (copied in space)."""
        corr = self.correspondence
        return tuple(corr is not None and spec.name in corr.edges for spec in self.inputs)

    @cached_property
    def outputs_vary(self) -> bool:
        """Whether an output joins a role that a space expansion duplicates or the pattern
        introduces: then the relations written differ between instances of one group."""
        corr = self.correspondence
        varying = {*(corr.expand_roles if corr else ()), *self.introduced}
        return any(spec.source in varying or spec.target in varying for spec in self.outputs)

    @cached_property
    def introduced(self) -> tuple[str, ...]:
        """Roles no input binds: frames the pattern introduces (the tip of a tip calibration).

        Only a time-only pattern may have them: integrating its inputs over time it determines
        a frame no single measurement touches. The planner binds such a role to a frame that a
        static query names and the SRG lacks (``docs/planner.md``).
        """
        bound = {role for spec in self.inputs for role in (spec.source, spec.target)}
        used = {role for spec in self.outputs for role in (spec.source, spec.target)}
        return tuple(role for role in self.roles if role in used - bound)


# --- loading and validation --------------------------------------------------------------------

_TOP = {
    "pattern",
    "service",
    "description",
    "roles",
    "type_vars",
    "inputs",
    "outputs",
    "correspondence",
    "cost",
    "parameters",
    "signature",
    "host_labels",
    "isolation",
}
_REQUIRED_TOP = ("pattern", "service", "roles", "inputs", "outputs")
_INPUT_KEYS = {"name", "from", "to", "type", "static", "mode", "measured", "not_from"}
_OUTPUT_KEYS = {"name", "from", "to", "type", "static", "mode"}
_CORR_KEYS = {"edges", "multiplicity", "expansions", "expand_roles", "independent"}
_COST_KEYS = {"rule", "gain", "time_gain", "latency"}


class _Checker:
    """Field checks that raise :class:`TemplateError` with the file and entry in the message."""

    def __init__(self, origin: str) -> None:
        self.origin = origin

    def fail(self, where: str, what: str) -> TemplateError:
        return TemplateError(f"{self.origin}: {where}: {what}")

    def mapping(
        self, where: str, value: Any, allowed: set[str], required: tuple[str, ...] = ()
    ) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(where, f"must be a mapping, got {value!r}")
        unknown = set(value) - allowed
        if unknown:
            raise self.fail(where, f"unknown field(s) {sorted(unknown)}")
        for key in required:
            if key not in value:
                raise self.fail(where, f"missing field {key!r}")
        return value

    def string(self, where: str, value: Any, pattern: re.Pattern[str] | None = None) -> str:
        if not isinstance(value, str) or not value:
            raise self.fail(where, f"must be a non-empty string, got {value!r}")
        if pattern is not None and not pattern.match(value):
            raise self.fail(where, f"{value!r} is not well-formed (expected {pattern.pattern})")
        return value

    def choice(self, where: str, value: Any, choices: Any) -> Any:
        if not isinstance(value, str | int | float) or value not in choices:
            raise self.fail(where, f"{value!r} is not one of {sorted(map(str, choices))}")
        return value

    def number(self, where: str, value: Any) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float) or value < 0:
            raise self.fail(where, f"must be a non-negative number, got {value!r}")
        return float(value)

    def string_list(self, where: str, value: Any, pattern: re.Pattern[str]) -> tuple[str, ...]:
        if not isinstance(value, list):
            raise self.fail(where, f"must be a list, got {value!r}")
        items = tuple(self.string(f"{where}[{i}]", v, pattern) for i, v in enumerate(value))
        if len(set(items)) != len(items):
            raise self.fail(where, f"duplicate entries in {list(items)}")
        return items


def _edge_type(c: _Checker, where: str, value: Any, type_vars: Mapping[str, Any]) -> str:
    value = c.string(where, value)
    if value.startswith("$"):
        if value[1:] not in type_vars:
            raise c.fail(where, f"type variable {value} is not declared in type_vars")
        return value
    return c.choice(where, value, EDGE_TYPES)


def _multiplicity(c: _Checker, where: str, value: Any) -> Multiplicity:
    match = _MULTIPLICITY.match(str(value)) if isinstance(value, int | str) else None
    if match is None or isinstance(value, bool):
        raise c.fail(where, f"{value!r} is not a multiplicity like 3, 2..4 or 4..*")
    lo = int(match.group(1))
    hi_text = match.group(2)
    hi = int(match.group(1)) if hi_text is None else None if hi_text == "*" else int(hi_text)
    if lo < 1 or (hi is not None and hi < lo):
        raise c.fail(where, f"{value!r} is empty or starts below 1")
    return Multiplicity(lo, hi)


def parse_template(data: Any, origin: str = "<template>") -> Template:
    """Validate the parsed YAML of one template file and return the :class:`Template`."""
    c = _Checker(origin)
    c.mapping("top level", data, _TOP, _REQUIRED_TOP)
    pattern = c.string("field 'pattern'", data["pattern"], _PATTERN_NAME)
    service = c.string("field 'service'", data["service"], _SERVICE_NAME)
    roles = c.string_list("field 'roles'", data["roles"], _ROLE_NAME)
    raw_vars = data.get("type_vars", {})
    c.mapping("field 'type_vars'", raw_vars, set(raw_vars or ()))
    type_vars: dict[str, tuple[str, ...]] = {}
    for var, domain in raw_vars.items():
        c.string(f"type_vars.{var}", var, _ROLE_NAME)
        if not isinstance(domain, list) or not domain:
            raise c.fail(f"type_vars.{var}", f"must be a non-empty list of types, got {domain!r}")
        type_vars[var] = tuple(c.choice(f"type_vars.{var}", t, EDGE_TYPES) for t in domain)

    def role(where: str, value: Any) -> str:
        return c.choice(where, value, roles)

    names: set[str] = set()

    def edge_name(where: str, value: Any) -> str:
        value = c.string(where, value, _ROLE_NAME)
        if value in names:
            raise c.fail(where, f"duplicate edge name {value!r}")
        names.add(value)
        return value

    def entries(key: str, allowed: set[str]) -> Iterator[tuple[str, dict[str, Any]]]:
        if not isinstance(data[key], list) or not data[key]:
            raise c.fail(f"field {key!r}", "must be a non-empty list")
        for i, entry in enumerate(data[key]):
            where = f"{key}[{i}]"
            yield where, c.mapping(where, entry, allowed, ("name", "from", "to", "type"))

    def head(where: str, entry: dict[str, Any]) -> tuple[str, str, str, str]:
        return (
            edge_name(f"{where}.name", entry["name"]),
            role(f"{where}.from", entry["from"]),
            role(f"{where}.to", entry["to"]),
            _edge_type(c, f"{where}.type", entry["type"], type_vars),
        )

    inputs = []
    for where, entry in entries("inputs", _INPUT_KEYS):
        for key in ("static", "measured"):
            if entry.get(key) is not None and not isinstance(entry[key], bool):
                raise c.fail(f"{where}.{key}", f"must be true or false, got {entry[key]!r}")
        mode = entry.get("mode")
        if mode is not None:
            c.choice(f"{where}.mode", mode, MODES)
        not_from = c.string_list(f"{where}.not_from", entry.get("not_from", []), _PATTERN_NAME)
        inputs.append(
            InputSpec(
                *head(where, entry),
                entry.get("static"),
                mode,
                entry.get("measured"),
                frozenset(not_from),
            )
        )
    bound_vars = {spec.type[1:] for spec in inputs if spec.type.startswith("$")}
    outputs = []
    for where, entry in entries("outputs", _OUTPUT_KEYS):
        name, source, target, edge_type = head(where, entry)
        if edge_type.startswith("$") and edge_type[1:] not in bound_vars:
            raise c.fail(f"{where}.type", f"type variable {edge_type} is bound by no input")
        static = c.choice(
            f"{where}.static", entry.get("static", "inherit"), ("inherit", True, False)
        )
        mode = c.choice(f"{where}.mode", entry.get("mode", "inherit"), ("inherit", *MODES))
        outputs.append(OutputSpec(name, source, target, edge_type, static, mode))
    correspondence = None
    if data.get("correspondence") is not None:
        where = "correspondence"
        raw = c.mapping(where, data["correspondence"], _CORR_KEYS, ("edges", "multiplicity"))
        input_names = [spec.name for spec in inputs]
        edges = c.string_list(f"{where}.edges", raw["edges"], _ROLE_NAME)
        for name in edges:
            c.choice(f"{where}.edges", name, input_names)
        expansions = c.string_list(f"{where}.expansions", raw.get("expansions", []), _ROLE_NAME)
        if not expansions:
            raise c.fail(f"{where}.expansions", "must list space and/or time")
        for name in expansions:
            c.choice(f"{where}.expansions", name, EXPANSIONS)
        expand_roles = c.string_list(
            f"{where}.expand_roles", raw.get("expand_roles", []), _ROLE_NAME
        )
        for name in expand_roles:
            role(f"{where}.expand_roles", name)
        independent = raw.get("independent", False)
        if not isinstance(independent, bool):
            raise c.fail(f"{where}.independent", f"must be true or false, got {independent!r}")
        for i, spec in enumerate(outputs):
            if {spec.source, spec.target} & set(expand_roles):
                raise c.fail(f"outputs[{i}]", "an output must not use a role of expand_roles")
        correspondence = Correspondence(
            edges,
            _multiplicity(c, f"{where}.multiplicity", raw["multiplicity"]),
            frozenset(expansions),
            expand_roles,
            independent,
        )
    raw_cost = c.mapping("field 'cost'", data.get("cost", {}), _COST_KEYS)
    cost = CostSpec(
        c.choice("cost.rule", raw_cost.get("rule", "sum"), COST_RULES),
        c.number("cost.gain", raw_cost.get("gain", 1.0)),
        c.number("cost.time_gain", raw_cost.get("time_gain", 1.0)),
        c.number("cost.latency", raw_cost.get("latency", 0.0)),
    )
    raw_parameters = data.get("parameters", {})
    parameters = c.mapping("field 'parameters'", raw_parameters, set(raw_parameters or ()))
    description = data.get("description", "")
    if not isinstance(description, str):
        raise c.fail("field 'description'", f"must be a string, got {description!r}")
    signature = c.choice("field 'signature'", data.get("signature", "step"), SIGNATURES)
    if signature == "inverse" and len(inputs) != 1:
        raise c.fail("field 'signature'", "an inverse has exactly one input")
    host_labels = frozenset(
        c.string_list("field 'host_labels'", data.get("host_labels", []), LABEL_PATTERN)
    )
    isolation = c.choice("field 'isolation'", data.get("isolation", "shared"), ISOLATIONS)
    template = Template(
        name=Path(origin).stem,
        pattern=pattern,
        service=service,
        description=description,
        roles=roles,
        type_vars=type_vars,
        inputs=tuple(inputs),
        outputs=tuple(outputs),
        correspondence=correspondence,
        cost=cost,
        parameters=dict(parameters),
        signature=signature,
        host_labels=host_labels,
        isolation=isolation,
    )
    if template.introduced and not template.time_only:
        raise c.fail(
            "field 'roles'",
            f"{', '.join(template.introduced)} bound by no input: only a time-only pattern "
            f"(a calibration, correspondence expansions [time]) may introduce a frame",
        )
    return template


def load_template(path: str | Path | Traversable) -> Template:
    """Load and validate one template file."""
    path = Path(path) if isinstance(path, str) else path
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise TemplateError(f"{path}: cannot read ({exc.strerror})") from None
    except yaml.YAMLError as exc:
        raise TemplateError(f"{path}: not valid YAML ({exc})") from None
    return parse_template(data, str(path))


def shipped_templates() -> Traversable:
    """The template directory shipped with the package: the top-level ``templates`` package's
    data files, found by :mod:`importlib.resources` in a wheel and in an editable install."""
    return importlib.resources.files("ubitrack_agent.templates")


def load_templates(directory: str | Path | Traversable | None = None) -> tuple[Template, ...]:
    """Load every ``*.yaml`` template of ``directory`` (default: :func:`shipped_templates`),
    sorted by file name. The patterns are those of the loaded set: a ``not_from`` naming a
    pattern no template of the set implements is an error."""
    directory = shipped_templates() if directory is None else directory
    if isinstance(directory, str):
        directory = Path(directory)
    files = (
        sorted(
            (entry for entry in directory.iterdir() if entry.name.endswith(".yaml")),
            key=lambda entry: entry.name,
        )
        if directory.is_dir()
        else []
    )
    if not files:
        raise TemplateError(f"{directory}: no *.yaml template files")
    templates = tuple(load_template(path) for path in files)
    patterns = sorted({template.pattern for template in templates})
    for path, template in zip(files, templates, strict=True):
        for i, spec in enumerate(template.inputs):
            unknown = sorted(spec.not_from - set(patterns))
            if unknown:
                raise TemplateError(
                    f"{path}: inputs[{i}].not_from: {', '.join(unknown)} is the pattern of no "
                    f"loaded template (loaded: {', '.join(patterns)})"
                )
    return templates
