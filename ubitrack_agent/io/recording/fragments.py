"""A provider's SRG fragment (``docs/protocol.md``) read back into the
:class:`~ubitrack_agent.io.provider.EdgeAnnouncement` objects a provider announces them with.

The recorder reads fragments from the network and the replayer from a file, so both are input
from outside: :func:`parse_fragment` returns an :class:`Announced` or raises
:class:`~.layout.RecordingError` naming the provider and the field, whatever the object holds.
The checks are those of the provider's own constructor (names, types, modes, numbers); the agent
checks what the replayer announces once more (``agent.announcements``). O(edges).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ubitrack_agent.core.names import shown
from ubitrack_agent.io.provider import EdgeAnnouncement
from ubitrack_agent.io.recording.layout import RecordingError
from ubitrack_agent.net.keys import validate_key_chunks

MAX_EDGES = 1000
"""Most edges one fragment may announce (the agent's limit too)."""
_FIELDS = {"name": "name", "from": "source", "to": "target", "type": "type", "static": "static"}
_OPTIONAL = ("mode", "sigma", "rate", "latency")


@dataclass(frozen=True)
class Announced:
    """A provider's announcement: its id, the machine it ran on and its edges."""

    provider: str
    host: str
    edges: tuple[EdgeAnnouncement, ...]

    def as_json(self) -> dict[str, Any]:
        """The fragment as the provider serves it (``io.provider.Provider``)."""
        return {
            "provider": self.provider,
            "host": self.host,
            "edges": [edge.as_json() for edge in self.edges],
        }


def parse_fragment(fragment: Any, provider: str | None = None) -> Announced:
    """The announcement in ``fragment`` (a JSON object); with ``provider``, it must name it."""
    if not isinstance(fragment, dict):
        raise RecordingError("fragment: expected a JSON object")
    name = fragment.get("provider")
    where = f"provider {shown(name)}"
    if not {"provider", "edges"} <= set(fragment) <= {"provider", "host", "edges"}:
        raise RecordingError(f'{where}: fragment must be {{"provider", "host", "edges"}}')
    try:
        validate_key_chunks(name, single_chunk=True)
        host = fragment.get("host", "unknown")
        validate_key_chunks(host, single_chunk=True)
    except ValueError as exc:
        raise RecordingError(f"{where}: {exc}") from None
    if provider is not None and name != provider:
        raise RecordingError(f"{where}: fragment of provider {shown(provider)} names another")
    edges = fragment["edges"]
    if not isinstance(edges, list) or not 0 < len(edges) <= MAX_EDGES:
        raise RecordingError(f"{where}: edges must be a list of 1 to {MAX_EDGES} entries")
    parsed = tuple(_edge(f"{where}, edges[{index}]", edge) for index, edge in enumerate(edges))
    names = [edge.name for edge in parsed]
    if len(set(names)) != len(names):
        raise RecordingError(f"{where}: two edges have the same name")
    return Announced(name, host, parsed)


def _edge(where: str, edge: Any) -> EdgeAnnouncement:
    if not isinstance(edge, dict):
        raise RecordingError(f"{where}: must be an object")
    unknown = sorted(set(edge) - set(_FIELDS) - set(_OPTIONAL))
    missing = sorted(set(_FIELDS) - {"static"} - set(edge))
    if unknown or missing:
        raise RecordingError(f"{where}: unknown fields {unknown}, missing fields {missing}")
    if not isinstance(edge.get("static", False), bool):
        raise RecordingError(f"{where}.static: must be true or false")
    for number in ("sigma", "rate", "latency"):
        value = edge.get(number)
        if value is not None and (isinstance(value, bool) or not isinstance(value, int | float)):
            raise RecordingError(f"{where}.{number}: must be a number")
        if isinstance(value, float) and not value < float("inf"):
            raise RecordingError(f"{where}.{number}: must be finite")
    values = {field: edge[key] for key, field in _FIELDS.items() if key in edge}
    values.update({key: edge[key] for key in _OPTIONAL if key in edge})
    try:
        return EdgeAnnouncement(**values)
    except (ValueError, TypeError) as exc:
        raise RecordingError(f"{where}: {exc}") from None
