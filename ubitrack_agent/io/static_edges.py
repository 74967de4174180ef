"""Static-edges files: the values of static SRG edges (calibration results), read and written.

A calibration store, or the simulated database (``ubitrack sim database --edges FILE``), serves
the edges of one such file as one provider. The format is YAML::

    provider: database             # the provider id that serves the edges
    edges:                         # one entry per edge: from, to, type and the value's fields
      - {from: C, to: HT, type: 6D, rotation: [0, 0, 0, 1], translation: [0.03, -0.06, 0.04]}
      - {from: WT, to: F1, type: 3D, position: [0.0, -0.2, -0.15]}
      - {from: C, to: IP, type: 3x4, matrix: [[700, 0, 320, 0], [0, 700, 240, 0], [0, 0, 1, 0]]}
      - {from: C, to: IP, type: intrinsics, matrix: [[700, 0, 320], [0, 700, 240], [0, 0, 1]],
         distortion: [0, 0, 0, 0, 0], image_size: [640, 480]}

The value fields are those of the measurement type (:mod:`ubitrack_agent.core.measurements`:
same names, units and conventions, i.e. metres, quaternions ``(x, y, z, w)``, OpenCV's camera
model); optional ones may be left out:

* ``6D``: ``rotation``, ``translation`` (a ``Pose``), and optionally ``covariance`` (6x6 over
  the left perturbation, rotation first; then an ``ErrorPose``);
* ``3D``: ``position``, optionally ``covariance`` (``Position3D``);
* ``3x4``: ``matrix`` (``Projection``);
* ``intrinsics``: ``matrix``, optionally ``distortion`` and ``image_size: [width, height]``
  (``CameraIntrinsics``).

Every edge is static; its server announces it (:meth:`StaticEdge.served_announcement`) with
the expected error :func:`announced_sigma` derives from the value's covariance, so the planner
weighs a calibrated value by its uncertainty. Its name is ``<from>_<to>``, or
``<from>_<to>_intrinsics`` for an ``intrinsics`` edge so that it can sit beside the ``3x4``
edge of the same camera; two entries with the same name are an error. The file stores no
timestamps: the reader stamps every value with the time it is given (a server's start time).
Validation is strict: an unknown key, a
missing field, a bad name, a value of the wrong shape or a non-number raises
:class:`StaticEdgesError` naming the file, the entry and the field, e.g.
``calib.yaml: edges[1] (C->HT 6D): Pose.rotation: not a unit quaternion (norm 2, more than
0.001 from 1): normalise it``. A quaternion typed by hand (four decimals) whose norm is within
:data:`~ubitrack_agent.core.measurements.TYPED_QUATERNION_TOLERANCE` (1e-3) of 1 is accepted
and normalised.

A calibration store (:mod:`ubitrack_agent.io.calibration_store`) also records where a value
came from and what it replaced: an entry may hold ``provenance`` (a flat mapping: when, which
flow, how many samples, its uncertainty) and ``history`` (up to :data:`MAX_HISTORY` earlier
values, newest first, each its value fields and provenance)::

      - {from: C, to: HT, type: 6D, rotation: [...], translation: [...], covariance: [...],
         provenance: {time: "2026-11-22T15:04:05Z", flow: averaging-1a2b, samples: 212},
         history: [{rotation: [...], translation: [...], provenance: {...}}]}

:func:`write_static_edges` writes such a file atomically: to a temporary file in the same
directory, flushed and ``fsync``-ed, then renamed over the target (``os.replace``) and the
directory ``fsync``-ed, so a reader sees the old file or the new one, never a partial one.
"""

from __future__ import annotations

import dataclasses
import os
import secrets
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from ubitrack_agent.core import (
    CameraIntrinsics,
    ErrorPose,
    Measurement,
    MeasurementError,
    Pose,
    Position3D,
    Projection,
    to_json,
)
from ubitrack_agent.core.measurements import normalise_typed_quaternion
from ubitrack_agent.core.uncertainty import expected_error
from ubitrack_agent.io.provider import EdgeAnnouncement
from ubitrack_agent.net.keys import validate_key_chunks

VALUE_TYPES: dict[str, tuple[type[Measurement], ...]] = {
    "6D": (Pose, ErrorPose),
    "3D": (Position3D,),
    "3x4": (Projection,),
    "intrinsics": (CameraIntrinsics,),
}
"""Edge types a static-edges file holds, and the measurement types their values may have."""

_EDGE_KEYS = ("from", "to", "type")
_RECORD_KEYS = ("provenance", "history")
MAX_HISTORY = 20
"""Earlier values a store keeps per edge."""

Scalar = str | int | float | bool | None


class StaticEdgesError(ValueError):
    """A static-edges file is unreadable or invalid; the message names the file, the entry and
    the field."""


@dataclass(frozen=True)
class StaticEdge:
    """An announced static edge and its value, with where the value came from and the values it
    replaced (newest first), as a calibration store keeps them."""

    announcement: EdgeAnnouncement
    value: Measurement
    provenance: Mapping[str, Scalar] | None = None
    history: tuple[Mapping[str, Any], ...] = ()
    """Earlier values: each the value's fields (as in the file) and its ``provenance``."""

    def served_announcement(self) -> EdgeAnnouncement:
        """The announcement a server of this edge makes: with the :func:`announced_sigma` of
        its value."""
        return dataclasses.replace(self.announcement, sigma=announced_sigma(self.value))


def announced_sigma(value: Measurement) -> float | None:
    """The RMS error (m) the planner is told for a stored value: the
    :func:`~ubitrack_agent.core.uncertainty.expected_error` of its covariance (a 6D value's at
    a 1 m lever arm), ``None`` (the planner's default) without a covariance."""
    covariance = getattr(value, "covariance", None)
    return None if covariance is None else expected_error(covariance)


def static_announcement(source: str, target: str, edge_type: str) -> EdgeAnnouncement:
    """The announcement of the static edge ``source -> target`` of ``edge_type``, named as in
    the module docstring; ``ValueError`` for a bad name or type."""
    suffix = "_intrinsics" if edge_type == "intrinsics" else ""
    return EdgeAnnouncement(
        source, target, edge_type, static=True, name=f"{source}_{target}{suffix}"
    )


def _value_fields(cls: type[Measurement]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Required and optional value fields of a measurement type (all but the timestamp)."""
    fields = [f for f in dataclasses.fields(cls) if f.name != "timestamp_ns"]
    required = tuple(
        f.name for f in fields if f.default is f.default_factory is dataclasses.MISSING
    )
    return required, tuple(f.name for f in fields if f.name not in required)


def _value_type(edge_type: str, entry: dict[str, Any]) -> type[Measurement]:
    """The measurement type of an entry: a 6D entry with a covariance is an ``ErrorPose``,
    any other the first of its edge type's."""
    if edge_type == "6D" and "covariance" in entry:
        return ErrorPose
    return VALUE_TYPES[edge_type][0]


def _numbers(value: Any) -> bool:
    """Whether ``value`` is a number or a (nested) list of numbers; booleans are not numbers."""
    if isinstance(value, list):
        return all(_numbers(item) for item in value)
    return isinstance(value, int | float) and not isinstance(value, bool)


class _Reader:
    """Checks one file's document; every error names the file."""

    def __init__(self, origin: str, timestamp_ns: int) -> None:
        self.origin = origin
        self.timestamp_ns = timestamp_ns

    def fail(self, where: str, what: str) -> StaticEdgesError:
        return StaticEdgesError(f"{self.origin}: {where}: {what}")

    def keys(
        self,
        where: str,
        data: dict[Any, Any],
        required: tuple[str, ...],
        optional: tuple[str, ...] = (),
    ) -> None:
        unknown = sorted(str(key) for key in data if key not in required + optional)
        if unknown:
            raise self.fail(where, f"unknown field(s) {unknown}; known: {[*required, *optional]}")
        if missing := [key for key in required if key not in data]:
            raise self.fail(where, f"missing field(s) {missing}")

    def name(self, where: str, value: Any) -> str:
        try:
            return validate_key_chunks(value, single_chunk=True)
        except ValueError as exc:
            raise self.fail(where, f"not a valid name: {exc}") from None

    def edge(self, where: str, entry: Any) -> StaticEdge:
        if not isinstance(entry, dict) or "type" not in entry:
            raise self.fail(where, "must be a mapping with from, to, type and the value's fields")
        edge_type = entry["type"]
        if not isinstance(edge_type, str) or edge_type not in VALUE_TYPES:
            raise self.fail(
                f"{where}.type", f"must be one of {list(VALUE_TYPES)}, got {edge_type!r}"
            )
        cls = _value_type(edge_type, entry)
        required, optional = _value_fields(cls)
        self.keys(where, entry, (*_EDGE_KEYS, *required), (*optional, *_RECORD_KEYS))
        source = self.name(f"{where}.from", entry["from"])
        target = self.name(f"{where}.to", entry["to"])
        where = f"{where} ({source}->{target} {edge_type})"
        history = entry.get("history", [])
        if not isinstance(history, list) or len(history) > MAX_HISTORY:
            raise self.fail(f"{where}.history", f"must be a list of at most {MAX_HISTORY} values")
        for i, earlier in enumerate(history):
            at = f"{where}.history[{i}]"
            if not isinstance(earlier, dict):
                raise self.fail(at, "must be a mapping of the value's fields and provenance")
            self.value(at, edge_type, earlier)
        return StaticEdge(
            static_announcement(source, target, edge_type),
            self.value(where, edge_type, entry),
            self.provenance(where, entry.get("provenance")),
            tuple(history),
        )

    def value(self, where: str, edge_type: str, entry: dict[str, Any]) -> Measurement:
        """The measurement of an entry's value fields (and checks its provenance)."""
        cls = _value_type(edge_type, entry)
        required, optional = _value_fields(cls)
        values = {k: v for k, v in entry.items() if k not in (*_EDGE_KEYS, *_RECORD_KEYS)}
        self.keys(where, values, required, optional)
        for key, value in values.items():
            if key != "image_size" and not _numbers(value):
                raise self.fail(where, f"{key}: must be a list of numbers, got {value!r}")
        self.provenance(where, entry.get("provenance"))
        try:
            if "rotation" in values:
                values["rotation"] = normalise_typed_quaternion(
                    f"{cls.__name__}.rotation", values["rotation"]
                )
            return cls(self.timestamp_ns, **values)
        except MeasurementError as exc:
            raise self.fail(where, str(exc)) from None

    def provenance(self, where: str, value: Any) -> Mapping[str, Scalar] | None:
        """Where a value came from: a flat mapping of names to strings and numbers."""
        if value is None:
            return None
        scalars = (str, int, float, bool, type(None))
        if not isinstance(value, dict) or not all(
            isinstance(k, str) and isinstance(v, scalars) for k, v in value.items()
        ):
            raise self.fail(f"{where}.provenance", "must be a mapping of names to plain values")
        return value

    def document(self, data: Any) -> tuple[str, list[StaticEdge]]:
        if not isinstance(data, dict):
            raise self.fail("file", "must be a mapping with provider and edges")
        self.keys("file", data, ("provider", "edges"))
        if not isinstance(data["edges"], list) or not data["edges"]:
            raise self.fail("edges", "must be a non-empty list")
        edges: dict[str, StaticEdge] = {}
        for i, entry in enumerate(data["edges"]):
            edge = self.edge(f"edges[{i}]", entry)
            name = edge.announcement.name
            if name in edges:
                raise self.fail(f"edges[{i}]", f"a second edge named {name!r} (<from>_<to>)")
            edges[name] = edge
        return self.name("provider", data["provider"]), list(edges.values())


def parse_static_edges(
    data: Any, timestamp_ns: int, origin: str = "<static edges>"
) -> tuple[str, list[StaticEdge]]:
    """``(provider id, edges)`` of a parsed static-edges document, values stamped
    ``timestamp_ns``; :class:`StaticEdgesError` (naming ``origin``) if it is invalid."""
    return _Reader(origin, timestamp_ns).document(data)


def read_static_edges(
    path: str | os.PathLike[str], timestamp_ns: int
) -> tuple[str, list[StaticEdge]]:
    """``(provider id, edges)`` of the static-edges file ``path``, values stamped
    ``timestamp_ns``; :class:`StaticEdgesError` if it is unreadable or invalid."""
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise StaticEdgesError(f"{path}: cannot read ({exc.strerror})") from None
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise StaticEdgesError(f"{path}: not valid YAML ({exc})") from None
    return parse_static_edges(data, timestamp_ns, str(path))


def value_fields(value: Measurement) -> dict[str, Any]:
    """A value's fields as a static-edges entry holds them (lists of numbers)."""
    return {k: v for k, v in to_json(value).items() if k not in ("type", "timestamp_ns")}


def format_static_edges(provider: str, edges: Iterable[StaticEdge]) -> str:
    """The static-edges file (YAML text) of ``edges`` served by ``provider``; ``ValueError``
    for a value the format cannot hold (its type is not one of :data:`VALUE_TYPES`)."""
    entries = []
    for edge in edges:
        announcement, value = edge.announcement, edge.value
        if type(value) not in VALUE_TYPES.get(announcement.type, ()):
            raise ValueError(
                f"edge {announcement.name}: a {type(value).__name__} cannot be stored as a "
                f"{announcement.type} static edge"
            )
        entry = {"from": announcement.source, "to": announcement.target, "type": announcement.type}
        entry |= value_fields(value)
        if edge.provenance is not None:
            entry["provenance"] = dict(edge.provenance)
        if edge.history:
            entry["history"] = [dict(earlier) for earlier in edge.history]
        entries.append(entry)
    document = {"provider": validate_key_chunks(provider, single_chunk=True), "edges": entries}
    return yaml.safe_dump(document, sort_keys=False, default_flow_style=None)


def write_static_edges(
    path: str | os.PathLike[str], provider: str, edges: Iterable[StaticEdge]
) -> None:
    """Write the static-edges file ``path`` atomically (see the module docstring); on any
    failure the previous file, if any, is left as it was and no temporary file remains."""
    path = Path(path)
    text = format_static_edges(provider, edges)
    temporary = path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp")
    descriptor = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(descriptor, "w", encoding="utf-8") as file:
            file.write(text)
            file.flush()
            os.fsync(file.fileno())
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    directory = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(directory)
    finally:
        os.close(directory)
