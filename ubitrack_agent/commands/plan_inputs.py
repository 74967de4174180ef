"""The documents ``ubitrack plan`` reads, merged into one SRG (``docs/planner.md``).

``ubitrack plan`` takes one or more YAML files and tells each one's format from its top-level
keys, so it plans on exactly the files the live system uses:

* a **setup file** (``edges``, optional ``name`` and ``description``;
  :func:`ubitrack_agent.graph.srg.parse_setup`): its edges as written;
* a **static-edges file** (``provider`` and ``edges``; :mod:`ubitrack_agent.io.static_edges`),
  as ``ubitrack store`` and ``ubitrack sim database --edges`` serve it and ``--dump`` writes
  it: each entry is a measured static edge of the file's provider, announced as its server
  announces it (``StaticEdge.served_announcement``: the ``sigma`` of the value's covariance);
* a **simulator scenario** (``frames``, ``art``, ``camera``, ``database``;
  :mod:`ubitrack_agent.sim_trackers.scenario`): the edges its simulators announce, i.e. the DTrack
  adapter's (the ``art`` section), the camera's and the calibration database's.

Announced edges (static-edges files and scenarios) become SRG edges as the live agent makes
them (:func:`ubitrack_agent.agent.announcements.provider_entries`: id ``<provider>/<name>``).

Merging: the edges of every document are put together. A static-edges entry *replaces* the
static edges of the same relation (``from``, ``to``, ``type``) that setups and scenarios
describe: the file says who serves that edge and how well (each replacement is reported). The
same static relation in two static-edges files is an error naming both entries; a relation
read the other way round (``HT->C`` beside ``C->HT``) is another edge.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import networkx as nx

from ubitrack_agent.agent.announcements import AnnouncementError, provider_entries
from ubitrack_agent.graph.srg import SetupError, add_setup_edge, new_srg, parse_setup, read_yaml
from ubitrack_agent.io.provider import EdgeAnnouncement
from ubitrack_agent.io.static_edges import StaticEdgesError, parse_static_edges
from ubitrack_agent.sim_trackers.database import static_edges
from ubitrack_agent.sim_trackers.scenario import ScenarioError, load_scenario
from ubitrack_agent.sim_trackers.sim_art import dtrack_adapter
from ubitrack_agent.sim_trackers.sim_camera import announcements

FORMATS = (
    "a setup file (edges: [...], docs/planner.md), a static-edges file (provider: ..., "
    "edges: [...], docs/simulators.md) or a simulator scenario (frames:, art:, camera:, "
    "database:, docs/simulators.md)"
)
"""The documents ``ubitrack plan`` accepts, as its errors name them."""


@dataclass(frozen=True)
class PlanEdge:
    """One edge for the plan: a setup-file entry, where it comes from (``file: edges[i]``, for
    errors and notes) and whether a static-edges file stores it."""

    where: str
    entry: dict[str, Any]
    stored: bool = False

    @property
    def relation(self) -> tuple[str, str, str]:
        """``(from, to, type)``."""
        return self.entry["from"], self.entry["to"], self.entry["type"]

    def describe(self) -> str:
        """``C->HT 6D (provider store)``."""
        source, target, edge_type = self.relation
        return f"{source}->{target} {edge_type} (provider {self.entry.get('provider')})"


def document_kind(data: Any, origin: str) -> str:
    """``"setup"``, ``"static-edges"`` or ``"scenario"``, from a parsed document's top-level
    keys; :class:`SetupError` naming the accepted formats for anything else."""
    if isinstance(data, dict):
        if "provider" in data:
            return "static-edges"
        if "frames" in data:
            return "scenario"
        if "edges" in data:
            return "setup"
    raise SetupError(f"{origin}: not a document ubitrack plan reads; expected {FORMATS}")


def announced_edges(
    origin: str,
    provider: str,
    edges: Sequence[EdgeAnnouncement],
    where: Sequence[str],
    stored: bool,
) -> list[PlanEdge]:
    """The plan edges of what ``provider`` announces in the file ``origin``, as the live agent
    turns them into SRG edges; ``where`` names each announcement in errors and notes."""
    try:
        entries = provider_entries(provider, [edge.as_json() for edge in edges])
    except AnnouncementError as exc:
        raise SetupError(f"{origin}: {exc}") from None
    return [PlanEdge(at, entry, stored) for at, entry in zip(where, entries, strict=True)]


def setup_edges(data: Any, origin: str) -> list[PlanEdge]:
    """The edges of a setup document, checked (errors name the file and the entry)."""
    parse_setup(data, origin)
    return [PlanEdge(f"{origin}: edges[{i}]", entry) for i, entry in enumerate(data["edges"])]


def stored_edges(data: Any, origin: str) -> list[PlanEdge]:
    """The edges of a static-edges document, each a measured static edge of its provider."""
    try:
        provider, edges = parse_static_edges(data, 0, origin)  # values are not planned on
    except StaticEdgesError as exc:
        raise SetupError(str(exc)) from None
    served = [edge.served_announcement() for edge in edges]
    where = [f"{origin}: edges[{i}]" for i in range(len(edges))]
    return announced_edges(origin, provider, served, where, stored=True)


def scenario_edges(origin: str) -> list[PlanEdge]:
    """The edges the simulators of the scenario file ``origin`` announce."""
    try:
        scenario = load_scenario(origin)
    except ScenarioError as exc:
        raise SetupError(str(exc)) from None
    art = scenario.art
    tracker = dtrack_adapter(art)
    database = static_edges(scenario.world, scenario.database_edges, 0)
    sections = [
        (art.provider, tracker.edges, "art"),
        (scenario.camera.provider, announcements(scenario.camera, scenario.world), "camera"),
        (scenario.database_provider, [e.served_announcement() for e in database], "database"),
    ]
    return [
        edge
        for provider, edges, section in sections
        for edge in announced_edges(
            origin, provider, edges, [f"{origin}: {section}: {e.name}" for e in edges], False
        )
    ]


def read_document(path: str) -> list[PlanEdge]:
    """The plan edges of one file, whatever its format (module docstring)."""
    data = read_yaml(path)
    kind = document_kind(data, path)
    if kind == "static-edges":
        return stored_edges(data, path)
    if kind == "scenario":
        return scenario_edges(path)
    return setup_edges(data, path)


def merge(edges: Iterable[PlanEdge]) -> tuple[list[PlanEdge], list[str]]:
    """The edges of several documents together, a stored edge replacing the static edges of its
    relation (module docstring), and a note per replaced edge; :class:`SetupError` naming both
    entries for a relation stored twice."""
    edges = list(edges)
    stored: dict[tuple[str, str, str], PlanEdge] = {}
    for edge in edges:
        if edge.stored and (first := stored.setdefault(edge.relation, edge)) is not edge:
            raise SetupError(
                f"{first.where} and {edge.where}: {edge.relation[0]}->{edge.relation[1]} "
                f"{edge.relation[2]} is stored in two static-edges files; give one of them"
            )
    kept, notes = [], []
    for edge in edges:
        replacement = stored.get(edge.relation)
        if not edge.stored and edge.entry.get("static", False) and replacement is not None:
            notes.append(f"{replacement.where} {replacement.describe()} replaces {edge.where}")
        else:
            kept.append(edge)
    return kept, notes


def build_srg(edges: Iterable[PlanEdge], name: str) -> nx.MultiDiGraph:
    """The SRG of ``edges``; :class:`SetupError` naming the entry (e.g. a duplicate id)."""
    srg = new_srg()
    srg.graph["name"] = name
    for edge in edges:
        add_setup_edge(srg, edge.entry, edge.where)
    return srg


def load_plan_srg(paths: Sequence[str]) -> tuple[nx.MultiDiGraph, list[str]]:
    """The SRG of the files ``paths`` (module docstring) and the notes on replaced edges."""
    edges, notes = merge(edge for path in paths for edge in read_document(path))
    return build_srg(edges, " + ".join(paths)), notes
