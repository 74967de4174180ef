"""Providers' SRG fragments (``docs/protocol.md``) turned into validated SRG edges.

A fragment is JSON ``{"provider": "<id>", "host": "<machine>", "edges": [{"name", "from", "to",
"type", "static", "mode", "sigma", "rate", "latency"}, ...]}`` (see
:class:`ubitrack_agent.io.provider.Provider`; ``host``, the machine the provider runs on, is
optional and becomes every edge's ``host``, for placement).
Each edge becomes a measured SRG edge with id ``<provider>/<name>``, which is also the tail of
its data key. Anything malformed raises :class:`AnnouncementError` naming the provider and the
field, and nothing else, whatever the bytes: the fragment is read by
``net.json_messages.load_object`` (at most :data:`MAX_FRAGMENT_BYTES`, bounded nesting), holds
at most :data:`MAX_EDGES` edges, names follow ``core.names`` (at most 128 characters) and the
numbers are finite and within ``graph.srg.QUALITY_BOUNDS``. The agent logs the rejection, counts
it and ignores that provider, never crashing.
"""

from __future__ import annotations

from collections.abc import Mapping, Set
from typing import Any

import networkx as nx

from ubitrack_agent.core.names import shown
from ubitrack_agent.graph.srg import SetupError, new_srg, parse_setup
from ubitrack_agent.net.json_messages import MessageError, load_object
from ubitrack_agent.net.keys import validate_key_chunks

MAX_FRAGMENT_BYTES = 1 << 20
MAX_EDGES = 1000
_EDGE_FIELDS = {"name", "from", "to", "type", "static", "mode", "sigma", "rate", "latency"}


class AnnouncementError(ValueError):
    """A provider's announcement is invalid."""


def _check(condition: bool, where: str, what: str) -> None:
    if not condition:
        raise AnnouncementError(f"{where}: {what}")


def fragment_entries(provider: str, payload: bytes) -> list[dict[str, Any]]:
    """The setup-file entries (``srg.parse_setup`` form) of ``provider``'s fragment."""
    where = f"provider {provider!r}"
    try:
        data = load_object(payload, MAX_FRAGMENT_BYTES)
    except MessageError as exc:
        raise AnnouncementError(f"{where}: fragment {exc.reason}") from None
    _check(
        {"provider", "edges"} <= set(data) <= {"provider", "host", "edges"},
        where,
        'fragment must be {"provider": ..., "host": ... (optional), "edges": [...]}',
    )
    _check(
        data["provider"] == provider, where, f"fragment names provider {shown(data['provider'])}"
    )
    host = data.get("host", "")
    if "host" in data:
        try:
            validate_key_chunks(host, single_chunk=True)
        except ValueError as exc:
            raise AnnouncementError(f"{where}: host: {exc}") from None
    return provider_entries(provider, data["edges"], host)


def provider_entries(provider: str, edges: Any, host: str = "") -> list[dict[str, Any]]:
    """The setup-file entries (``srg.parse_setup`` form) of the announced ``edges`` of
    ``provider`` (``EdgeAnnouncement.as_json`` objects) running on ``host`` (empty: unknown):
    ids ``<provider>/<name>``, the provider and host set; :class:`AnnouncementError` naming the
    provider and the field if invalid."""
    where = f"provider {provider!r}"
    _check(
        isinstance(edges, list) and 0 < len(edges) <= MAX_EDGES,
        where,
        f"edges must be a list of 1 to {MAX_EDGES} entries",
    )
    entries, names = [], set()
    for index, edge in enumerate(edges):
        at = f"{where}, edges[{index}]"
        _check(isinstance(edge, dict), at, "must be an object")
        unknown = sorted(set(edge) - _EDGE_FIELDS)
        _check(not unknown, at, f"unknown fields {unknown}")
        for field_name in ("name", "from", "to"):
            value = edge.get(field_name)
            try:
                validate_key_chunks(value, single_chunk=True)
            except ValueError as exc:
                raise AnnouncementError(f"{at}.{field_name}: {exc}") from None
        _check(edge["name"] not in names, at, f"duplicate edge name {edge['name']}")
        names.add(edge["name"])
        entry = {k: v for k, v in edge.items() if k != "name"}
        entries.append(
            {
                **entry,
                "id": f"{provider}/{edge['name']}",
                "provider": provider,
                **({"host": host} if host else {}),
            }
        )
    try:
        parse_setup({"edges": entries}, origin=where)  # types, modes, numbers, frames
    except SetupError as exc:
        raise AnnouncementError(str(exc)) from None
    return entries


def build_srg(
    fragments: Mapping[str, list[dict[str, Any]]], without: Set[str] = frozenset()
) -> nx.MultiDiGraph:
    """The live SRG of every accepted provider's edges, less the edge ids ``without`` (those
    whose data stopped: ``agent.liveness``)."""
    entries = [
        entry
        for provider in sorted(fragments)
        for entry in fragments[provider]
        if entry["id"] not in without
    ]
    if not entries:
        return new_srg()
    return parse_setup({"name": "live", "edges": entries}, origin="live SRG")
