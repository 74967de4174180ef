"""Scenario files: the simulated world and its sensors, read from YAML with strict checks.

A scenario names the frames (a tree with fixed or trajectory-driven placements), the image
planes of cameras, and the settings of the simulated A.R.T. tracker, camera and calibration
database (``docs/simulators.md`` describes every field; ``scenarios/paper_figure1.yaml`` is
the default, the setup of figure 1 of Pustka et al., ISMAR 2006). Any unknown key, missing
field or wrong value raises :class:`ScenarioError` naming the file and the field, e.g.
``paper.yaml: art.noise.position_mm: must be a number >= 0, got 'x'``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from ubitrack_agent.core import MeasurementError
from ubitrack_agent.core.measurements import normalise_typed_quaternion
from ubitrack_agent.io.static_edges import VALUE_TYPES
from ubitrack_agent.net.keys import validate_key_chunks
from ubitrack_agent.sim_trackers.trajectories import LissajousPath
from ubitrack_agent.sim_trackers.world import (
    FixedPlacement,
    Frame,
    ImagePlane,
    Placement,
    World,
    WorldError,
)

DEFAULT_SCENARIO = Path(__file__).with_name("scenarios") / "paper_figure1.yaml"

EDGE_TYPES = tuple(VALUE_TYPES)
"""Edge types the calibration database can derive from the world: those of a static-edges
file."""


class ScenarioError(ValueError):
    """A scenario file is unreadable or invalid; the message names the file and the field."""


@dataclass(frozen=True)
class Noise:
    """Isotropic noise: standard deviations per axis."""

    position_mm: float
    rotation_deg: float


@dataclass(frozen=True)
class ArtSettings:
    """The simulated A.R.T. tracker and the DTrack adapter reading it."""

    provider: str
    frame: str
    rate: float
    port: int
    bodies: dict[int, str]
    static_bodies: tuple[str, ...]
    markers: dict[int, str]
    noise: Noise
    dropout: float


@dataclass(frozen=True)
class CameraSettings:
    """The simulated camera: which image plane, which features, rate, noise and losses."""

    provider: str
    image_plane: str
    features: tuple[str, ...]
    rate: float
    noise_px: float
    dropout: float
    occlusion: float


@dataclass(frozen=True)
class DatabaseEdge:
    """A static edge the calibration database serves; its value is the world's truth."""

    source: str
    target: str
    type: str


@dataclass(frozen=True)
class Scenario:
    """A whole scenario: the world plus the simulators' settings."""

    path: str
    world: World
    art: ArtSettings
    camera: CameraSettings
    database_provider: str
    database_edges: tuple[DatabaseEdge, ...]
    seed: int


class FieldReader:
    """Checks values of one file; every error names the file and the dotted field path."""

    def __init__(self, path: str) -> None:
        self.path = path

    def fail(self, where: str, what: str) -> ScenarioError:
        return ScenarioError(f"{self.path}: {where}: {what}")

    def mapping(
        self, where: str, value: Any, required: tuple[str, ...], optional: tuple[str, ...] = ()
    ) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(where, f"must be a mapping, got {type(value).__name__}")
        unknown = sorted(str(k) for k in value if k not in required + optional)
        if unknown:
            raise self.fail(where, f"unknown field(s) {unknown}; known: {[*required, *optional]}")
        missing = [k for k in required if k not in value]
        if missing:
            raise self.fail(where, f"missing field(s) {missing}")
        return value

    def number(
        self, where: str, value: Any, low: float = -math.inf, high: float = math.inf
    ) -> float:
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        if not ok or not math.isfinite(value) or not low <= value <= high:
            raise self.fail(where, f"must be a number in [{low}, {high}], got {value!r}")
        return float(value)

    def integer(self, where: str, value: Any, low: int, high: int) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise self.fail(where, f"must be an integer in [{low}, {high}], got {value!r}")
        return value

    def vector(self, where: str, value: Any, length: int) -> tuple[float, ...]:
        if not isinstance(value, list) or len(value) != length:
            raise self.fail(where, f"must be a list of {length} numbers, got {value!r}")
        return tuple(self.number(f"{where}[{i}]", v) for i, v in enumerate(value))

    def name(self, where: str, value: Any) -> str:
        try:
            return validate_key_chunks(value, single_chunk=True)
        except ValueError as exc:
            raise self.fail(where, f"not a valid name: {exc}") from None

    def frame(self, where: str, value: Any, world: World) -> str:
        name = self.name(where, value)
        if name not in world.frames:
            raise self.fail(where, f"unknown frame {name!r}; frames: {sorted(world.frames)}")
        return name

    def probability(self, where: str, value: Any) -> float:
        return self.number(where, value, 0.0, 1.0)


def _placement(read: FieldReader, where: str, spec: dict[str, Any]) -> Placement:
    if "trajectory" in spec:
        if {"translation", "rotation", "euler_deg"} & set(spec):
            raise read.fail(where, "a trajectory excludes translation, rotation and euler_deg")
        return _trajectory(read, f"{where}.trajectory", spec["trajectory"])
    if "rotation" in spec and "euler_deg" in spec:
        raise read.fail(where, "give rotation (quaternion x, y, z, w) or euler_deg, not both")
    rotation: tuple[float, ...] = (0.0, 0.0, 0.0, 1.0)
    if "rotation" in spec:
        rotation = read.vector(f"{where}.rotation", spec["rotation"], 4)
        try:
            rotation = tuple(normalise_typed_quaternion(f"{where}.rotation", rotation))
        except MeasurementError as exc:
            raise ScenarioError(f"{read.path}: {exc}") from None
    elif "euler_deg" in spec:
        angles = read.vector(f"{where}.euler_deg", spec["euler_deg"], 3)
        rotation = tuple(Rotation.from_euler("xyz", angles, degrees=True).as_quat())
    translation = read.vector(f"{where}.translation", spec.get("translation", [0, 0, 0]), 3)
    return FixedPlacement(rotation, translation)


def _trajectory(read: FieldReader, where: str, spec: Any) -> LissajousPath:
    spec = read.mapping(
        where, spec, ("type", "centre", "amplitude", "frequency"), ("phase", "look_at")
    )
    if spec["type"] != "lissajous":
        raise read.fail(f"{where}.type", f"must be 'lissajous', got {spec['type']!r}")
    look_at = spec.get("look_at")
    return LissajousPath(
        centre=read.vector(f"{where}.centre", spec["centre"], 3),
        amplitude=read.vector(f"{where}.amplitude", spec["amplitude"], 2),
        frequency=read.vector(f"{where}.frequency", spec["frequency"], 2),
        phase=read.number(f"{where}.phase", spec.get("phase", 0.0)),
        look_at=None if look_at is None else read.vector(f"{where}.look_at", look_at, 3),
    )


def _frames(read: FieldReader, spec: Any) -> list[Frame]:
    if not isinstance(spec, dict) or not spec:
        raise read.fail("frames", "must be a non-empty mapping of frame names")
    frames = []
    for name, body in spec.items():
        where = f"frames.{name}"
        read.name(where, name)
        body = read.mapping(
            where, body or {}, (), ("parent", "translation", "rotation", "euler_deg", "trajectory")
        )
        if "parent" not in body:
            if set(body):
                raise read.fail(where, "the root frame (no parent) takes no placement")
            frames.append(Frame(name))
            continue
        parent = read.name(f"{where}.parent", body["parent"])
        frames.append(Frame(name, parent, _placement(read, where, body)))
    return frames


def _image_planes(read: FieldReader, spec: Any) -> list[ImagePlane]:
    spec = {} if spec is None else spec
    if not isinstance(spec, dict):
        raise read.fail("image_planes", f"must be a mapping, got {type(spec).__name__}")
    planes = []
    for name, body in spec.items():
        where = f"image_planes.{name}"
        read.name(where, name)
        body = read.mapping(where, body, ("camera", "intrinsics", "image_size"), ("distortion",))
        k = read.mapping(
            f"{where}.intrinsics", body["intrinsics"], ("fx", "fy", "cx", "cy"), ("skew",)
        )
        fx, fy = (read.number(f"{where}.intrinsics.{a}", k[a], 1e-9) for a in ("fx", "fy"))
        cx, cy = (read.number(f"{where}.intrinsics.{a}", k[a]) for a in ("cx", "cy"))
        skew = read.number(f"{where}.intrinsics.skew", k.get("skew", 0.0))
        size = body["image_size"]
        if not isinstance(size, list) or len(size) != 2:
            raise read.fail(f"{where}.image_size", f"must be [width, height], got {size!r}")
        width, height = (read.integer(f"{where}.image_size", v, 1, 100_000) for v in size)
        distortion = body.get("distortion", [])
        if not isinstance(distortion, list) or len(distortion) not in (0, 4, 5, 8, 12, 14):
            raise read.fail(f"{where}.distortion", "must be a list of 0, 4, 5, 8, 12 or 14 numbers")
        planes.append(
            ImagePlane(
                name=name,
                camera=read.name(f"{where}.camera", body["camera"]),
                matrix=np.array([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]),
                distortion=np.array(
                    read.vector(f"{where}.distortion", distortion, len(distortion))
                ),
                image_size=(width, height),
            )
        )
    return planes


def _id_map(
    read: FieldReader, where: str, spec: Any, world: World, first_id: int
) -> dict[int, str]:
    if not isinstance(spec, dict):
        raise read.fail(where, "must be a mapping of DTrack ids to frame names")
    return {
        read.integer(f"{where}.{key}", key, first_id, 1_000_000): read.frame(
            f"{where}.{key}", value, world
        )
        for key, value in spec.items()
    }


def _art(read: FieldReader, spec: Any, world: World) -> ArtSettings:
    spec = read.mapping(
        "art",
        spec,
        ("provider", "frame", "rate", "port", "bodies", "noise"),
        ("static_bodies", "markers", "dropout"),
    )
    noise = read.mapping("art.noise", spec["noise"], ("position_mm", "rotation_deg"))
    bodies = _id_map(read, "art.bodies", spec["bodies"], world, 0)
    static = spec.get("static_bodies", [])
    if not isinstance(static, list):
        raise read.fail("art.static_bodies", "must be a list of frame names")
    for i, name in enumerate(static):
        if name not in bodies.values():
            raise read.fail(f"art.static_bodies[{i}]", f"{name!r} is not one of art.bodies")
    return ArtSettings(
        provider=read.name("art.provider", spec["provider"]),
        frame=read.frame("art.frame", spec["frame"], world),
        rate=read.number("art.rate", spec["rate"], 0.1, 10_000.0),
        port=read.integer("art.port", spec["port"], 1, 65535),
        bodies=bodies,
        static_bodies=tuple(static),
        markers=_id_map(read, "art.markers", spec.get("markers", {}), world, 1),
        noise=Noise(
            position_mm=read.number("art.noise.position_mm", noise["position_mm"], 0.0),
            rotation_deg=read.number("art.noise.rotation_deg", noise["rotation_deg"], 0.0),
        ),
        dropout=read.probability("art.dropout", spec.get("dropout", 0.0)),
    )


def _camera(read: FieldReader, spec: Any, world: World) -> CameraSettings:
    spec = read.mapping(
        "camera",
        spec,
        ("provider", "image_plane", "features", "rate"),
        ("noise_px", "dropout", "occlusion"),
    )
    plane = read.name("camera.image_plane", spec["image_plane"])
    if plane not in world.image_planes:
        raise read.fail("camera.image_plane", f"unknown image plane {plane!r}")
    features = spec["features"]
    if not isinstance(features, list) or not features:
        raise read.fail("camera.features", "must be a non-empty list of frame names")
    return CameraSettings(
        provider=read.name("camera.provider", spec["provider"]),
        image_plane=plane,
        features=tuple(
            read.frame(f"camera.features[{i}]", f, world) for i, f in enumerate(features)
        ),
        rate=read.number("camera.rate", spec["rate"], 0.1, 10_000.0),
        noise_px=read.number("camera.noise_px", spec.get("noise_px", 0.0), 0.0),
        dropout=read.probability("camera.dropout", spec.get("dropout", 0.0)),
        occlusion=read.probability("camera.occlusion", spec.get("occlusion", 0.0)),
    )


def _database(read: FieldReader, spec: Any, world: World) -> tuple[str, tuple[DatabaseEdge, ...]]:
    spec = read.mapping("database", spec, ("provider", "edges"))
    if not isinstance(spec["edges"], list) or not spec["edges"]:
        raise read.fail("database.edges", "must be a non-empty list")
    edges = []
    for i, edge in enumerate(spec["edges"]):
        where = f"database.edges[{i}]"
        edge = read.mapping(where, edge, ("from", "to", "type"))
        if edge["type"] not in EDGE_TYPES:
            raise read.fail(f"{where}.type", f"must be one of {EDGE_TYPES}, got {edge['type']!r}")
        source = read.frame(f"{where}.from", edge["from"], world)
        if edge["type"] in ("3x4", "intrinsics"):
            target = read.name(f"{where}.to", edge["to"])
            plane = world.image_planes.get(target)
            if plane is None or plane.camera != source:
                raise read.fail(where, f"{target!r} is not an image plane of camera {source!r}")
        else:
            target = read.frame(f"{where}.to", edge["to"], world)
            if not world.is_static(source, target):
                raise read.fail(where, f"{source}->{target} moves: a database edge must be static")
        edges.append(DatabaseEdge(source, target, edge["type"]))
    return read.name("database.provider", spec["provider"]), tuple(edges)


def read_yaml(path: str | os.PathLike[str]) -> Any:
    """The YAML document in ``path``; :class:`ScenarioError` if unreadable or invalid."""
    try:
        return yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read ({exc.strerror})") from None
    except yaml.YAMLError as exc:
        raise ScenarioError(f"{path}: not valid YAML ({exc})") from None


def load_scenario(path: str | os.PathLike[str] | None = None) -> Scenario:
    """Read and check a scenario file (default: the paper's figure-1 setup)."""
    path = Path(path) if path is not None else DEFAULT_SCENARIO
    read = FieldReader(str(path))
    data = read.mapping(
        "scenario",
        read_yaml(path),
        ("frames", "art", "camera", "database"),
        ("image_planes", "seed"),
    )
    try:
        world = World(_frames(read, data["frames"]), _image_planes(read, data.get("image_planes")))
    except WorldError as exc:
        raise read.fail("frames", str(exc)) from None
    provider, edges = _database(read, data["database"], world)
    return Scenario(
        path=str(path),
        world=world,
        art=_art(read, data["art"], world),
        camera=_camera(read, data["camera"], world),
        database_provider=provider,
        database_edges=edges,
        seed=read.integer("seed", data.get("seed", 1), 0, 2**32 - 1),
    )
