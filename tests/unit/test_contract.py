"""The contract between a pattern's two declarations: its template and its service class.

A spatial relationship pattern is described by a YAML template (what the planner matches,
section 5.2.1) and run by a registered service class (what a worker computes).
:func:`contract_problems` checks that the two agree, as the agent connects them: a component's
ports are the template's edge names (``graph.dataflow``; ``IF[2]`` is the third space-expanded
binding of port ``IF``, ``agent.materialise``) and its parameters are the template's.

* the service is registered;
* its input ports are the template's input edges and its output ports the output edges;
* each input port accepts every SRG type the template admits on that edge (each value of a type
  variable over its domain), i.e. one of the measurement classes with that ``SRG_TYPE``;
* its correspondence ports are the template's correspondence edges, and ``MIN_CORRESPONDENCES``
  is the multiplicity's lower bound (a service takes any number above it, so a template may not
  bound the multiplicity from above);
* the parameters have the same names, and the template's values the kind (flag, number,
  string) of the service's defaults;
* a probe runs the service on noise-free synthetic scenes, for every type binding, every accepted
  measurement class and every allowed expansion, and checks that it yields every output edge
  with the template's type and the true value, and that it reads every parameter it declares.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import replace
from itertools import product
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bench.synthetic import CAMERA_MATRIX, rng_for
from ubitrack_agent.core import (
    MEASUREMENT_TYPES,
    CameraIntrinsics,
    ErrorPose,
    Measurement,
    Pose,
    Position2D,
    Position3D,
    Projection,
    Rotation3D,
    quaternions,
    se3,
)
from ubitrack_agent.graph.templates import InputSpec, Multiplicity, Template, load_templates
from ubitrack_agent.services.components.basic import Inversion
from ubitrack_agent.services.components.fusion import Fusion
from ubitrack_agent.services.registry import SERVICES, Service, lookup

Lookup = Callable[[str], type[Service]]
Transform = tuple[np.ndarray, np.ndarray]
"""A pose ``(q, t)``: the pose of B in A for an edge A->B, of a role in the world for a scene."""

TIME = 1_000
TOLERANCE = 1e-6
"""Largest difference from the truth of a noise-free probe (matrix entries, metres, pixels)."""

MAKERS: dict[type[Measurement], Callable[[np.ndarray, np.ndarray], Measurement]] = {
    Pose: lambda q, t: Pose(TIME, q, t),
    ErrorPose: lambda q, t: ErrorPose(TIME, q, t, 1e-6 * np.eye(6)),
    Position3D: lambda q, t: Position3D(TIME, t),
    Rotation3D: lambda q, t: Rotation3D(TIME, q),
    Position2D: lambda q, t: Position2D(TIME, (CAMERA_MATRIX @ t)[:2] / (CAMERA_MATRIX @ t)[2]),
    Projection: lambda q, t: Projection(TIME, CAMERA_MATRIX @ se3.to_matrix(*se3.invert(q, t))[:3]),
    CameraIntrinsics: lambda q, t: CameraIntrinsics(TIME, CAMERA_MATRIX),
}
"""The measurement of an edge A->B from the pose of B in A. An image plane is a camera frame
(OpenCV axes) with the intrinsic matrix ``CAMERA_MATRIX``: a 2D edge I->F is the pixel of F in
image I, a 3x4 edge C->I projects points of C into image I. Set types (``PositionList3D``...)
carry several edges and have no maker."""


def classes_of(srg_type: str) -> tuple[type[Measurement], ...]:
    """The measurement classes of an SRG edge type (their ``SRG_TYPE``)."""
    return tuple(cls for cls in MEASUREMENT_TYPES.values() if srg_type == cls.SRG_TYPE)


def admitted(template: Template, spec: InputSpec) -> tuple[str, ...]:
    """The SRG types the template admits on an input: a literal, or a type variable's domain."""
    return template.type_vars[spec.type[1:]] if spec.type.startswith("$") else (spec.type,)


def type_bindings(template: Template) -> list[dict[str, str]]:
    """Every assignment of the template's type variables over their domains."""
    names = sorted(template.type_vars)
    domains = (template.type_vars[name] for name in names)
    return [dict(zip(names, combo, strict=True)) for combo in product(*domains)]


def resolve(edge_type: str, binding: Mapping[str, str]) -> str:
    """An edge type under a type variable binding."""
    return binding[edge_type[1:]] if edge_type.startswith("$") else edge_type


def _names(classes: Any) -> str:
    return ", ".join(sorted(cls.__name__ for cls in classes)) or "nothing"


def _ports_problems(template: Template, service: type[Service]) -> list[str]:
    problems = []
    for kind, edges, ports in (
        ("input", [spec.name for spec in template.inputs], list(service.INPUTS)),
        ("output", [spec.name for spec in template.outputs], list(service.OUTPUTS)),
    ):
        problems += [
            f"{kind} {edge}: the service has no {kind} port {edge} (its {kind}s: {ports})"
            for edge in edges
            if edge not in ports
        ]
        problems += [
            f"{kind} port {port}: the template has no {kind} edge {port} (its {kind}s: {edges})"
            for port in ports
            if port not in edges
        ]
    for spec in template.inputs:
        port = service.INPUTS.get(spec.name)
        for srg_type in admitted(template, spec) if port is not None else ():
            if not set(classes_of(srg_type)) & set(port.types):
                problems.append(
                    f"input {spec.name}: the template admits {srg_type} "
                    f"({_names(classes_of(srg_type))}), port {spec.name} accepts only "
                    f"{_names(port.types)}"
                )
    return problems


def _correspondence_problems(template: Template, service: type[Service]) -> list[str]:
    corr = template.correspondence
    edges = sorted(corr.edges) if corr is not None else []
    problems = []
    if edges != sorted(service.CORRESPONDENCE):
        problems.append(
            f"correspondence: the template's edges are {edges}, "
            f"the service's CORRESPONDENCE {sorted(service.CORRESPONDENCE)}"
        )
    if corr is not None and corr.multiplicity.lo != service.MIN_CORRESPONDENCES:
        problems.append(
            f"multiplicity {corr.multiplicity}: the template's lower bound is "
            f"{corr.multiplicity.lo}, the service's MIN_CORRESPONDENCES "
            f"{service.MIN_CORRESPONDENCES}"
        )
    if corr is not None and corr.multiplicity.hi is not None:
        problems.append(
            f"multiplicity {corr.multiplicity}: the template's upper bound is "
            f"{corr.multiplicity.hi}, the service takes any number of correspondences"
        )
    return problems


def _same_kind(value: Any, default: Any) -> bool:
    """A template may set another value than the service's default (its instances run with
    it), but of the default's kind: a flag, a number or a string."""
    if isinstance(value, bool) or isinstance(default, bool):
        return isinstance(value, bool) and isinstance(default, bool)
    if isinstance(default, int | float):
        return isinstance(value, int | float)
    return type(value) is type(default)


def _parameter_problems(template: Template, service: type[Service]) -> list[str]:
    given, declared = template.parameters, service.PARAMETERS
    problems = [
        f"parameter {name}: given by the template ({given[name]!r}), unknown to the service "
        f"(a worker refuses it)"
        for name in given
        if name not in declared
    ]
    problems += [
        f"parameter {name}: declared by the service (default {declared[name]!r}), "
        f"missing from the template"
        for name in declared
        if name not in given
    ]
    problems += [
        f"parameter {name}: the template gives {given[name]!r}, not of the kind of the "
        f"service's default {declared[name]!r}"
        for name in given
        if name in declared and not _same_kind(given[name], declared[name])
    ]
    return problems


# --- the probe: run the service on noise-free synthetic scenes ----------------------------------


def _image_roles(template: Template, binding: Mapping[str, str]) -> set[str]:
    """Roles that are image planes: targets of 3x4 edges and sources of 2D edges."""
    roles = set()
    for spec in (*template.inputs, *template.outputs):
        edge_type = resolve(spec.type, binding)
        if edge_type == "3x4":
            roles.add(spec.target)
        elif edge_type == "2D":
            roles.add(spec.source)
    return roles


def _place(rng: np.random.Generator, image: bool) -> Transform:
    """A role's pose in the world: image planes are cameras near the origin looking along +z,
    every other frame lies 1.5 to 2.5 m in front of them, randomly turned."""
    if image:
        q = Rotation.from_rotvec(rng.uniform(-0.1, 0.1, 3)).as_quat()
        return q, np.array([*rng.uniform(-0.3, 0.3, 2), 0.0])
    q = Rotation.random(rng=rng).as_quat()
    return q, np.array([*rng.uniform(-0.3, 0.3, 2), rng.uniform(1.5, 2.5)])


def _relation(world: Mapping[str, Transform], source: str, target: str) -> Transform:
    """The pose of ``target`` in ``source``."""
    return se3.compose(*se3.invert(*world[source]), *world[target])


def _static_links(template: Template) -> list[tuple[str, str]]:
    """Role pairs that keep their relation over a time expansion: static inputs (outside the
    correspondence) and outputs (the results of a time expansion are static)."""
    corr = template.correspondence
    edges = set(corr.edges) if corr is not None else set()
    pairs = [(s.source, s.target) for s in template.inputs if s.name not in edges]
    return [*pairs, *((s.source, s.target) for s in template.outputs)]


def _pivots(template: Template, binding: Mapping[str, str]) -> set[str]:
    """Points (roles only ever the target of a 3D or 2D edge) held by static links in two or
    more roles: the tip of a pointer is fixed in its marker and, on the pivot, in the tracker,
    yet the marker turns about it. Such a point keeps only its position."""
    edges = (*template.inputs, *template.outputs)
    sources = {spec.source for spec in edges}
    points = {
        spec.target
        for spec in edges
        if spec.target not in sources
        and all(resolve(e.type, binding) in ("3D", "2D") for e in edges if e.target == spec.target)
    }
    holders = [b for _, b in _static_links(template)]
    return {point for point in points if holders.count(point) > 1}


def _rigid_groups(template: Template, pivots: set[str]) -> list[list[str]]:
    """Roles that keep their relative poses over a time expansion: joined by a static link
    (:func:`_static_links`) other than one holding a pivot (:func:`_pivots`)."""
    group = {role: {role} for role in template.roles}
    for a, b in _static_links(template):
        if b in pivots:
            continue
        merged = group[a] | group[b]
        for role in merged:
            group[role] = merged
    unique = {id(members): members for members in group.values()}.values()
    return [[role for role in template.roles if role in members] for members in unique]


def _moved(
    world: dict[str, Transform],
    template: Template,
    groups: list[list[str]],
    pivots: set[str],
    images: set[str],
    rng: np.random.Generator,
) -> dict[str, Transform]:
    """The scene at another instant: the group holding a camera (else the first) and the
    pivots stay, every other rigid group is placed anew, its first role drawn like
    :func:`_place` and the others carried along; a group holding a pivot is turned at random
    about it instead (one pivot per group)."""
    anchor = next((g for g in groups if images & set(g)), groups[0])
    held = {a: b for a, b in _static_links(template) if b in pivots}
    moved = dict(world)
    for members in groups:
        if members is anchor or set(members) <= pivots:
            continue
        lead = members[0]
        pivot = next((held[role] for role in members if role in held), None)
        if pivot is None:
            new_lead = _place(rng, lead in images)
        else:
            turn, centre = Rotation.random(rng=rng).as_quat(), world[pivot][1]
            new_lead = se3.compose(turn, centre - quaternions.rotate(turn, centre), *world[lead])
        for role in members:
            moved[role] = se3.compose(*new_lead, *_relation(world, lead, role))
    return moved


def _scenes(
    template: Template,
    binding: Mapping[str, str],
    expansion: str,
    minimum: int,
    rng: np.random.Generator,
) -> tuple[dict[str, Transform], list[dict[str, Transform]]]:
    """The scene of the non-corresponding edges and outputs, and one scene per correspondence
    copy: ``lo`` copies with fresh duplicated roles (space) or the scene at ``max(lo, minimum)``
    instants (time)."""
    images = _image_roles(template, binding)
    world = {role: _place(rng, role in images) for role in template.roles}
    corr = template.correspondence
    if expansion == "space":
        roles = corr.expand_roles
        copies = [
            {**world, **{role: _place(rng, role in images) for role in roles}}
            for _ in range(corr.multiplicity.lo)
        ]
        return world, copies
    if expansion == "time":
        pivots = _pivots(template, binding)
        groups = _rigid_groups(template, pivots)
        copies = [
            _moved(world, template, groups, pivots, images, rng)
            for _ in range(max(corr.multiplicity.lo, minimum))
        ]
        return copies[-1], copies
    return world, []


def _distance(produced: Measurement, expected: Measurement) -> float:
    """Largest difference of two measurements of one type (projections up to scale)."""
    if isinstance(produced, Projection):
        a, b = (m.matrix / np.linalg.norm(m.matrix) for m in (produced, expected))
        return float(min(np.abs(a - b).max(), np.abs(a + b).max()))
    if isinstance(produced, Pose | ErrorPose):
        values = [se3.to_matrix(m.rotation, m.translation) for m in (produced, expected)]
    elif isinstance(produced, Rotation3D):
        values = [quaternions.to_matrix(m.rotation) for m in (produced, expected)]
    elif isinstance(produced, CameraIntrinsics):
        values = [m.matrix for m in (produced, expected)]
    else:
        values = [m.position for m in (produced, expected)]
    return float(np.abs(values[0] - values[1]).max())


class _ReadRecorder(dict):
    """Parameters that remember which of them were read."""

    def __init__(self, parameters: Mapping[str, Any]) -> None:
        super().__init__(parameters)
        self.read: set[str] = set()

    def __getitem__(self, key: str) -> Any:
        self.read.add(key)
        return super().__getitem__(key)

    def get(self, key: str, default: Any = None) -> Any:
        self.read.add(key)
        return super().get(key, default)


def _recording(service: type[Service]) -> type[Service]:
    """``service`` whose parameters remember which of them were read, from ``__init__`` on."""

    class Recording(service):  # type: ignore[misc, valid-type]
        @property
        def parameters(self) -> _ReadRecorder:
            return self._recorder

        @parameters.setter
        def parameters(self, value: Mapping[str, Any]) -> None:
            self._recorder = _ReadRecorder(value)

    return Recording


def _output_problems(
    template: Template,
    binding: Mapping[str, str],
    produced: Mapping[str, Any],
    world: Mapping[str, Transform],
    label: str,
) -> list[str]:
    names = [spec.name for spec in template.outputs]
    problems = [f"{label}: unknown output {name}" for name in produced if name not in names]
    for spec in template.outputs:
        edge_type = resolve(spec.type, binding)
        out = produced.get(spec.name)
        if not isinstance(out, Measurement):
            problems.append(f"{label}: no measurement for output {spec.name} ({edge_type})")
        elif edge_type != out.SRG_TYPE:
            problems.append(
                f"{label}: output {spec.name} is a {type(out).__name__} ({out.SRG_TYPE}), "
                f"the template declares {edge_type}"
            )
        else:
            maker = next(cls for cls in MAKERS if edge_type == cls.SRG_TYPE)
            expected = MAKERS[maker](*_relation(world, spec.source, spec.target))
            error = _distance(out, expected)
            if not error <= TOLERANCE:
                problems.append(
                    f"{label}: output {spec.name} is off the true "
                    f"{spec.source}->{spec.target} by {error:.3g}"
                )
    return problems


def _probe_problems(template: Template, service: type[Service]) -> list[str]:
    """Run ``service`` on noise-free scenes (see the module docstring)."""
    rng = rng_for(f"contract {template.name}")
    corr = template.correspondence
    edges = set(corr.edges) if corr is not None else set()
    expansions = sorted(corr.expansions) if corr is not None else ["none"]
    problems, read = [], set()
    for binding in type_bindings(template):
        choices = []
        for spec in template.inputs:
            edge_type = resolve(spec.type, binding)
            makeable = [c for c in service.INPUTS[spec.name].types if c in MAKERS]
            choices.append([c for c in makeable if edge_type == c.SRG_TYPE])
            if not choices[-1]:
                problems.append(f"input {spec.name}: no maker for a {edge_type} its port accepts")
        for classes, expansion in product(product(*choices), expansions):
            kinds = ", ".join(
                f"{spec.name} {cls.__name__}"
                for spec, cls in zip(template.inputs, classes, strict=True)
            )
            label = f"probe ({expansion + ' expansion' if corr else 'unexpanded'}; {kinds})"
            instance = _recording(service)(dict(template.parameters))
            world, copies = _scenes(
                template, binding, expansion, instance.min_correspondences(), rng
            )
            values = {
                spec.name: [MAKERS[cls](*_relation(s, spec.source, spec.target)) for s in copies]
                if spec.name in edges
                else MAKERS[cls](*_relation(world, spec.source, spec.target))
                for spec, cls in zip(template.inputs, classes, strict=True)
            }
            try:
                produced = instance.compute(values, TIME)
            except Exception as exc:  # any failure is a finding of the probe
                problems.append(f"{label}: compute raised {type(exc).__name__}: {exc}")
                continue
            finally:
                read |= instance.parameters.read
            problems += _output_problems(template, binding, produced, world, label)
    problems += [
        f"parameter {name}: declared by the service, never read (by compute or "
        f"min_correspondences) on any probe"
        for name in service.PARAMETERS
        if name not in read
    ]
    return problems


def contract_problems(template: Template, services: Lookup = lookup) -> list[str]:
    """Every disagreement between ``template`` and the service it names, as sentences naming
    the pattern, the template, the service and the port or parameter; empty if they agree.

    The declarations are compared first; the probe runs only if they agree (otherwise it could
    not even bind the inputs).
    """
    where = f"{template.pattern} (template {template.name}, service {template.service})"
    try:
        service = services(template.service)
    except KeyError:
        return [f"{where}: service {template.service} is not registered"]
    problems = (
        _ports_problems(template, service)
        + _correspondence_problems(template, service)
        + _parameter_problems(template, service)
    )
    if not problems:
        problems = _probe_problems(template, service)
    return [f"{where}: {problem}" for problem in dict.fromkeys(problems)]


# --- the shipped catalogue ----------------------------------------------------------------------

SHIPPED = {template.name: template for template in load_templates()}


@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_shipped_template_agrees_with_its_service(name):
    assert contract_problems(SHIPPED[name]) == []


def test_every_registered_service_but_the_relay_runs_a_shipped_template():
    lookup("relay")  # loads every component module
    assert set(SERVICES) - {t.service for t in SHIPPED.values()} == {"relay"}


# --- deliberately broken pairs: each disagreement is named --------------------------------------

FUSION = SHIPPED["fusion"]
WHERE = "MultiTrackerFusion (template fusion, service fusion): "


def only(service: type[Service]) -> Lookup:
    """A registry holding just ``service``."""
    return lambda name: service


def test_an_unregistered_service():
    problems = contract_problems(replace(FUSION, service="fusion_v2"))
    assert problems == [
        "MultiTrackerFusion (template fusion, service fusion_v2): "
        "service fusion_v2 is not registered"
    ]


def test_a_type_the_port_does_not_accept():
    template = replace(FUSION, type_vars={"T": (*FUSION.type_vars["T"], "2D")})
    assert contract_problems(template) == [
        WHERE + "input AB: the template admits 2D (Position2D, PositionList2D), "
        "port AB accepts only ErrorPose, Pose, Position3D, Rotation3D"
    ]


def test_a_renamed_port():
    class Renamed(Fusion):
        INPUTS = {"BA": Fusion.INPUTS["AB"]}
        CORRESPONDENCE = ("BA",)

    assert contract_problems(FUSION, only(Renamed)) == [
        WHERE + "input AB: the service has no input port AB (its inputs: ['BA'])",
        WHERE + "input port BA: the template has no input edge BA (its inputs: ['AB'])",
        WHERE + "correspondence: the template's edges are ['AB'], the service's "
        "CORRESPONDENCE ['BA']",
    ]


def test_a_renamed_output():
    class Renamed(Fusion):
        OUTPUTS = ("mean",)

    assert contract_problems(FUSION, only(Renamed)) == [
        WHERE + "output fused: the service has no output port fused (its outputs: ['mean'])",
        WHERE + "output port mean: the template has no output edge mean (its outputs: ['fused'])",
    ]


@pytest.mark.parametrize(
    ("multiplicity", "problem"),
    [
        (Multiplicity(3, None), "the template's lower bound is 3, the service's "),
        (Multiplicity(2, 4), "the template's upper bound is 4, the service takes any number"),
    ],
)
def test_a_wrong_multiplicity(multiplicity, problem):
    correspondence = replace(FUSION.correspondence, multiplicity=multiplicity)
    problems = contract_problems(replace(FUSION, correspondence=correspondence))
    assert len(problems) == 1
    assert problems[0].startswith(WHERE + f"multiplicity {multiplicity}: {problem}")


def test_a_missing_correspondence():
    class Plain(Fusion):
        CORRESPONDENCE = ()

    assert contract_problems(FUSION, only(Plain)) == [
        WHERE + "correspondence: the template's edges are ['AB'], the service's CORRESPONDENCE []"
    ]


def test_parameters_that_differ():
    class Extra(Fusion):
        PARAMETERS = {**Fusion.PARAMETERS, "gain": 2.0}

    assert contract_problems(FUSION, only(Extra)) == [
        WHERE + "parameter gain: declared by the service (default 2.0), missing from the template"
    ]
    given = replace(FUSION, parameters={**FUSION.parameters, "gain": 2.0})
    assert contract_problems(given) == [
        WHERE + "parameter gain: given by the template (2.0), unknown to the service "
        "(a worker refuses it)"
    ]
    other_value = replace(FUSION, parameters={**FUSION.parameters, "default_sigma": 0.01})
    assert contract_problems(other_value) == []  # a template may tune its instances
    wrong_kind = replace(FUSION, parameters={**FUSION.parameters, "default_sigma": "0.01"})
    assert contract_problems(wrong_kind) == [
        WHERE + "parameter default_sigma: the template gives '0.01', not of the kind of the "
        "service's default 0.001"
    ]


def test_a_parameter_that_is_never_read():
    class Unread(Fusion):
        PARAMETERS = {**Fusion.PARAMETERS, "min_motion_pairs": 2}

    template = replace(FUSION, parameters={**FUSION.parameters, "min_motion_pairs": 2})
    assert contract_problems(template, only(Unread)) == [
        WHERE + "parameter min_motion_pairs: declared by the service, never read (by compute "
        "or min_correspondences) on any probe"
    ]


def test_an_output_of_another_type():
    template = replace(FUSION, outputs=(replace(FUSION.outputs[0], type="6D"),))
    problems = contract_problems(template)
    assert (
        WHERE
        + (
            "probe (space expansion; AB Position3D): output fused is a Position3D (3D), "
            "the template declares 6D"
        )
        in problems
    )
    assert len(problems) == 2  # 3D and 3R


def test_an_output_the_service_computes_the_other_way_round():
    inversion = SHIPPED["inversion"]
    swapped = replace(inversion.outputs[0], source="A", target="B")
    problems = contract_problems(replace(inversion, outputs=(swapped,)))
    assert problems
    assert all(
        p.startswith("Inversion (template inversion, service inversion): probe (unexpanded; ")
        and "output BA is off the true A->B by" in p
        for p in problems
    )


def test_a_service_that_fails_on_an_admitted_input():
    class Failing(Inversion):
        def compute(self, values, timestamp_ns):
            if isinstance(values["AB"], Rotation3D):
                raise ValueError("rotations are not supported")
            return super().compute(values, timestamp_ns)

    problems = contract_problems(SHIPPED["inversion"], only(Failing))
    assert problems == [
        "Inversion (template inversion, service inversion): probe (unexpanded; "
        "AB Rotation3D): compute raised ValueError: rotations are not supported"
    ]
