"""The spatial relationship graph (SRG) and the setup files that describe one.

An SRG (paper section 2.3) is a directed multigraph ``G = (V, E)``: nodes are coordinate frames
(or orientation-free points), edges are spatial relationships with the attributes of section
2.2. Parallel edges are normal (several estimates of the same relationship). Edges describe the
*availability* of measurements, not values, so an edge carries no pose, only what the planner
needs: type, static/dynamic, push/pull, measured/inferred, provider, quality and provenance.

The graph is a :class:`networkx.MultiDiGraph` whose edge keys are edge ids (strings) and whose
edge data are the keys of :class:`EdgeAttrs` (``type``, ``static``, ...), so networkx
algorithms and matchers can read them directly.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import networkx as nx
import yaml

from ubitrack_agent.core.names import check_name, shown

EDGE_TYPES: frozenset[str] = frozenset({"6D", "3D", "2D", "3x4", "3R", "intrinsics"})
"""Edge types (section 2.2): the ``SRG_TYPE`` names of :mod:`ubitrack_agent.core.measurements`."""

MODES: frozenset[str] = frozenset({"push", "pull"})
"""Push edges deliver samples as they are measured; pull edges are evaluated on request."""

DEFAULT_SIGMA = 1e-3
"""Expected RMS error (metres, or the metric error a 2D error induces) when a setup gives none."""

QUALITY_BOUNDS: dict[str, tuple[float, float]] = {
    "sigma": (0.0, 1e3),
    "rate": (0.0, 1e5),
    "latency": (0.0, 60.0),
}
"""The closed range of each number an edge may announce: ``sigma`` (m), ``rate`` (Hz, 0 for
unknown), ``latency`` (s). NaN, infinities and numbers outside are refused (:class:`SetupError`),
so the planner's arithmetic stays finite (``docs/planner.md``, "Setup files")."""


class SetupError(ValueError):
    """A setup file or SRG entry is invalid; the message names the file, the entry and the field."""


def check_node_name(name: Any, where: str) -> str:
    """Return ``name`` if it is a frame name usable inside a zenoh key expression
    (:func:`ubitrack_agent.core.names.check_name`), else raise :class:`SetupError`."""
    try:
        return check_name(name)
    except ValueError as exc:
        raise SetupError(f"{where}: frame name {exc}") from None


@dataclass(frozen=True)
class Quality:
    """Quality of an edge: expected error variance (m^2), update rate (Hz), latency (s)."""

    variance: float = DEFAULT_SIGMA**2
    rate: float = 0.0
    latency: float = 0.0


@dataclass(frozen=True)
class EdgeAttrs:
    """Attributes of one SRG edge (section 2.2), stored as the networkx edge data.

    ``sources`` is the provenance used for bookkeeping (section 5.1): the ids of the measured
    edges the value depends on (a measured edge's sources are its own id). ``derivation`` is the
    id of the pattern step that inferred the edge (``None`` when measured). ``host`` is the
    machine a measured edge's provider runs on (empty: unknown), for placing the workers that
    read it (``agent.placement``).
    """

    type: str
    static: bool = False
    mode: str = "push"
    measured: bool = True
    provider: str = ""
    host: str = ""
    quality: Quality = field(default_factory=Quality)
    sources: frozenset[str] = frozenset()
    derivation: str | None = None

    def as_data(self) -> dict[str, Any]:
        """The dict stored on the networkx edge (shallow: ``quality`` stays a dataclass)."""
        return {name: getattr(self, name) for name in self.__dataclass_fields__}


def new_srg() -> nx.MultiDiGraph:
    """An empty SRG."""
    return nx.MultiDiGraph()


def add_measured_edge(
    srg: nx.MultiDiGraph,
    source: str,
    target: str,
    edge_type: str,
    *,
    static: bool = False,
    mode: str = "push",
    provider: str | None = None,
    quality: Quality | None = None,
    edge_id: str | None = None,
    host: str = "",
) -> str:
    """Add a measured edge and return its id (default ``"A->B:6D"``, ``#2``... for parallels).

    The default provider is ``"database"`` for static edges and the source frame otherwise (a
    tracker is usually named after its own frame).
    """
    where = f"edge {source}->{target}"
    check_node_name(source, where)
    check_node_name(target, where)
    if source == target:
        raise SetupError(f"{where}: an edge must join two different frames")
    if edge_type not in EDGE_TYPES:
        raise SetupError(
            f"{where}: unknown type {edge_type!r}, expected one of {sorted(EDGE_TYPES)}"
        )
    if mode not in MODES:
        raise SetupError(f"{where}: unknown mode {mode!r}, expected push or pull")
    if edge_id is None:
        edge_id = f"{source}->{target}:{edge_type}"
        base, n = edge_id, 1
        while edge_id in edge_ids(srg):
            n += 1
            edge_id = f"{base}#{n}"
    elif edge_id in edge_ids(srg):
        raise SetupError(f"{where}: duplicate edge id {edge_id!r}")
    attrs = EdgeAttrs(
        type=edge_type,
        static=static,
        mode=mode,
        measured=True,
        provider=provider if provider is not None else ("database" if static else source),
        host=host,
        quality=quality or Quality(),
        sources=frozenset({edge_id}),
    )
    srg.add_edge(source, target, key=edge_id, **attrs.as_data())
    srg.graph.setdefault("edge_index", {})[edge_id] = (source, target)
    return edge_id


def edge_ids(srg: nx.MultiDiGraph) -> Mapping[str, tuple[str, str]]:
    """Map of edge id -> (source, target) for every edge of ``srg``."""
    return srg.graph.get("edge_index", {})


def _without_edges(srg: nx.MultiDiGraph, dropped: set[str]) -> nx.MultiDiGraph:
    """A copy of ``srg`` without the edges ``dropped`` (a frame left with no edge goes too)."""
    out = new_srg()
    for u, v, key, data in srg.edges(keys=True, data=True):
        if key not in dropped:
            out.add_edge(u, v, key=key, **data)
            out.graph.setdefault("edge_index", {})[key] = (u, v)
    return out


def remove_provider(srg: nx.MultiDiGraph, provider: str) -> nx.MultiDiGraph:
    """A copy of ``srg`` without the edges of ``provider`` (a sensor that disappeared)."""
    dropped = {key for _, _, key, name in srg.edges(keys=True, data="provider") if name == provider}
    return _without_edges(srg, dropped)


def static_relation_edges(srg: nx.MultiDiGraph, a: str, b: str) -> list[str]:
    """The ids of the measured static edges between frames ``a`` and ``b``, in either
    direction and of any type (e.g. a stored calibration of ``a->b``), sorted."""
    return sorted(
        key
        for u, v, key, data in srg.edges(keys=True, data=True)
        if {u, v} == {a, b} and data["static"] and data["measured"]
    )


def remove_static_relation(srg: nx.MultiDiGraph, a: str, b: str) -> nx.MultiDiGraph:
    """A copy of ``srg`` without :func:`static_relation_edges` of ``a`` and ``b`` (the SRG a
    recalibration of ``a->b`` is planned on)."""
    return _without_edges(srg, set(static_relation_edges(srg, a, b)))


# --- setup files -------------------------------------------------------------------------------

_EDGE_KEYS: dict[str, type | tuple[type, ...]] = {
    "from": str,
    "to": str,
    "type": str,
    "static": bool,
    "mode": str,
    "provider": str,
    "host": str,
    "id": str,
    "sigma": (int, float),
    "rate": (int, float),
    "latency": (int, float),
}
_REQUIRED_EDGE_KEYS = ("from", "to", "type")
_TOP_KEYS = {"name", "description", "edges"}


def _check_value(where: str, key: str, value: Any, want: type | tuple[type, ...]) -> None:
    ok = isinstance(value, want) and not (isinstance(value, bool) and want is not bool)
    if not ok:
        names = want.__name__ if isinstance(want, type) else " or ".join(t.__name__ for t in want)
        raise SetupError(f"{where}, field {key!r}: expected {names}, got {shown(value)}")
    if key in QUALITY_BOUNDS:
        low, high = QUALITY_BOUNDS[key]
        if not low <= value <= high:  # also refuses NaN; an int of any size compares exactly
            raise SetupError(
                f"{where}, field {key!r}: must be a finite number in [{low:g}, {high:g}], "
                f"got {shown(value)}"
            )


def add_setup_edge(srg: nx.MultiDiGraph, entry: Any, where: str) -> str:
    """Check one edge entry of a setup file (see :func:`parse_setup`) and add it to ``srg``;
    returns its id; :class:`SetupError` prefixed with ``where`` if it is invalid."""
    if not isinstance(entry, dict):
        raise SetupError(f"{where}: must be a mapping, got {entry!r}")
    unknown = set(entry) - set(_EDGE_KEYS)
    if unknown:
        raise SetupError(f"{where}: unknown field(s) {sorted(unknown)}")
    for key in _REQUIRED_EDGE_KEYS:
        if key not in entry:
            raise SetupError(f"{where}: missing field {key!r}")
    for key, value in entry.items():
        _check_value(where, key, value, _EDGE_KEYS[key])
    sigma = float(entry.get("sigma", DEFAULT_SIGMA))
    quality = Quality(sigma**2, float(entry.get("rate", 0.0)), float(entry.get("latency", 0.0)))
    try:
        return add_measured_edge(
            srg,
            entry["from"],
            entry["to"],
            entry["type"],
            static=entry.get("static", False),
            mode=entry.get("mode", "push"),
            provider=entry.get("provider"),
            quality=quality,
            edge_id=entry.get("id"),
            host=_host(where, entry.get("host", "")),
        )
    except SetupError as exc:
        raise SetupError(f"{where}: {exc}") from None


def _host(where: str, name: str) -> str:
    """The ``host`` of an edge entry: empty (unknown) or a name (``core.names``)."""
    if not name:
        return ""
    try:
        return check_name(name)
    except ValueError as exc:
        raise SetupError(f"{where}, field 'host': {exc}") from None


def parse_setup(data: Any, origin: str = "<setup>") -> nx.MultiDiGraph:
    """Build an SRG from the parsed YAML of a setup file; ``origin`` names it in errors.

    Format: a mapping with ``edges`` (a list of edge entries) and optional ``name`` and
    ``description``. Each edge entry has ``from``, ``to``, ``type`` and optional ``static``
    (default false), ``mode`` (push/pull, default push), ``provider``, ``host`` (the machine
    its provider runs on, for placement), ``id``, ``sigma``
    (expected RMS error in metres), ``rate`` (Hz) and ``latency`` (s). Unknown keys are errors.
    """
    if not isinstance(data, dict):
        raise SetupError(f"{origin}: top level must be a mapping with an 'edges' list")
    unknown = set(data) - _TOP_KEYS
    if unknown:
        raise SetupError(f"{origin}: unknown top-level key(s) {sorted(unknown)}")
    edges = data.get("edges")
    if not isinstance(edges, list) or not edges:
        raise SetupError(f"{origin}: 'edges' must be a non-empty list")
    srg = new_srg()
    srg.graph["name"] = data.get("name", origin)
    for i, entry in enumerate(edges):
        add_setup_edge(srg, entry, f"{origin}: edges[{i}]")
    return srg


def read_yaml(path: str | Path) -> Any:
    """The YAML document in ``path``; :class:`SetupError` naming the file if it is unreadable
    or not YAML."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise SetupError(f"{path}: cannot read ({exc.strerror})") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise SetupError(f"{path}: not valid YAML ({exc})") from None


def load_setup(path: str | Path) -> nx.MultiDiGraph:
    """Load and validate a setup file (YAML); raises :class:`SetupError` naming the file."""
    return parse_setup(read_yaml(path), str(path))
