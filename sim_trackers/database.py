"""Calibration database: the static edges of a setup, served over zenoh as one provider.

As in the paper's figure 6, calibration results that do not change at run time (the camera's
projection ``C -> IP``, the camera-to-head-target calibration ``C -> HT``, the marker positions
``WT -> F1..F5`` on the world target, the augmentation's placement ``WT -> A``) come from a
database rather than a tracker. The values are the scenario's ground truth: 6D edges as
:class:`~ubitrack_agent.core.Pose`, 3D edges as :class:`~ubitrack_agent.core.Position3D`, an
image plane's ``3x4`` edge as the :class:`~ubitrack_agent.core.Projection` ``K [I | 0]`` and its
``intrinsics`` edge (named ``<camera>_<plane>_intrinsics``, so it can sit beside the 3x4 edge)
as :class:`~ubitrack_agent.core.CameraIntrinsics` with the distortion coefficients.

The values can also come from a file of static edges (real calibration results), one entry
per edge with the measurement's fields (``docs/simulators.md``)::

    provider: database
    edges:
      - {from: C, to: HT, type: 6D, rotation: [0, 0, 0, 1], translation: [0.03, -0.06, 0.04]}
      - {from: WT, to: F1, type: 3D, position: [0.0, -0.2, -0.15]}
      - {from: C, to: IP, type: 3x4, matrix: [[700, 0, 320, 0], [0, 700, 240, 0], [0, 0, 1, 0]]}

:func:`dump_edges` writes that file from any list of edges, e.g. the scenario's.

The provider publishes each value once; its data keys keep answering queries with it
(:class:`ubitrack_agent.net.transport.LatestValuePublisher`), so consumers started later fetch it.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass

import yaml

from sim_trackers.scenario import EDGE_TYPES, DatabaseEdge, FieldReader, read_yaml
from sim_trackers.world import World
from ubitrack_agent.core import (
    CameraIntrinsics,
    Measurement,
    MeasurementError,
    Pose,
    Position3D,
    Projection,
    to_json,
)
from ubitrack_agent.io.provider import EdgeAnnouncement

VALUE_TYPES: dict[str, type[Measurement]] = {
    "6D": Pose,
    "3D": Position3D,
    "3x4": Projection,
    "intrinsics": CameraIntrinsics,
}


@dataclass(frozen=True)
class StaticEdge:
    """An announced static edge and its value."""

    announcement: EdgeAnnouncement
    value: Measurement


def _value(world: World, edge: DatabaseEdge, timestamp_ns: int) -> Measurement:
    if edge.type == "6D":
        return Pose(timestamp_ns, *world.pose(edge.source, edge.target, timestamp_ns))
    if edge.type == "3D":
        return Position3D(timestamp_ns, world.pose(edge.source, edge.target, timestamp_ns)[1])
    plane = world.image_planes[edge.target]
    if edge.type == "3x4":
        return Projection(timestamp_ns, plane.projection_matrix())
    return CameraIntrinsics(timestamp_ns, plane.matrix, plane.distortion, plane.image_size)


def _announcement(source: str, target: str, edge_type: str) -> EdgeAnnouncement:
    suffix = "_intrinsics" if edge_type == "intrinsics" else ""
    return EdgeAnnouncement(
        source, target, edge_type, static=True, name=f"{source}_{target}{suffix}"
    )


def static_edges(
    world: World, edges: tuple[DatabaseEdge, ...], timestamp_ns: int
) -> list[StaticEdge]:
    """The database's edges with their values from ``world`` (stamped ``timestamp_ns``)."""
    return [
        StaticEdge(
            _announcement(edge.source, edge.target, edge.type), _value(world, edge, timestamp_ns)
        )
        for edge in edges
    ]


def _value_fields(cls: type[Measurement]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Required and optional value fields of a measurement type (all but the timestamp)."""
    fields = [f for f in dataclasses.fields(cls) if f.name != "timestamp_ns"]
    required = tuple(
        f.name for f in fields if f.default is f.default_factory is dataclasses.MISSING
    )
    return required, tuple(f.name for f in fields if f.name not in required)


def load_edges_file(
    path: str | os.PathLike[str], timestamp_ns: int
) -> tuple[str, list[StaticEdge]]:
    """``(provider id, edges)`` of a static-edges file; :class:`ScenarioError` names the
    file and the field of any mistake."""
    read = FieldReader(str(path))
    data = read.mapping("file", read_yaml(path), ("provider", "edges"))
    if not isinstance(data["edges"], list) or not data["edges"]:
        raise read.fail("edges", "must be a non-empty list")
    edges = []
    for i, entry in enumerate(data["edges"]):
        where = f"edges[{i}]"
        if not isinstance(entry, dict) or "type" not in entry:
            raise read.fail(where, "must be a mapping with a type")
        edge_type = entry["type"]
        cls = VALUE_TYPES.get(edge_type)
        if cls is None:
            raise read.fail(f"{where}.type", f"must be one of {EDGE_TYPES}, got {edge_type!r}")
        required, optional = _value_fields(cls)
        entry = read.mapping(where, entry, ("from", "to", "type", *required), optional)
        values = {k: v for k, v in entry.items() if k not in ("from", "to", "type")}
        if "image_size" in values:
            values["image_size"] = tuple(values["image_size"])
        try:
            announcement = _announcement(
                read.name(f"{where}.from", entry["from"]),
                read.name(f"{where}.to", entry["to"]),
                edge_type,
            )
            edges.append(StaticEdge(announcement, cls(timestamp_ns, **values)))
        except MeasurementError as exc:
            raise read.fail(where, str(exc)) from None
    return read.name("provider", data["provider"]), edges


def dump_edges(provider: str, edges: list[StaticEdge]) -> str:
    """The static-edges file (YAML) holding ``edges``; :func:`load_edges_file` reads it."""
    entries = []
    for edge in edges:
        values = {k: v for k, v in to_json(edge.value).items() if k not in ("type", "timestamp_ns")}
        entries.append(
            {
                "from": edge.announcement.source,
                "to": edge.announcement.target,
                "type": edge.announcement.type,
                **values,
            }
        )
    document = {"provider": provider, "edges": entries}
    return yaml.safe_dump(document, sort_keys=False, default_flow_style=None)
