"""Sensor-side API: announce SRG edges and publish their measurements.

A few lines make a tracker, camera or calibration database part of the middleware::

    edges = [
        EdgeAnnouncement("ART", "HT", "6D", rate=60.0, sigma=0.0005),
        EdgeAnnouncement("ART", "WT", "6D", static=True),
    ]
    with (
        open_session(settings) as session,
        Provider(session, KeySpace(settings.key_prefix), "art", edges, settings.host_name)
        as provider,
    ):
        provider.publish("ART_HT", pose)      # edge names default to <from>_<to>
        ...                                   # leaving the block closes the provider

The provider serves its SRG fragment (JSON, see ``docs/protocol.md``) on
``<root>/fragment/<id>``, naming the machine it runs on (``host``, default the machine's host
name: the agent places the workers reading its edges near it), then declares its liveliness
token ``<root>/provider/<id>``; the agent sees the token, fetches the fragment and adds the
edges to the live SRG. Each edge's data key also answers queries with the latest value, so a
worker started later still gets a static edge's value. Closing (leaving the ``with`` block,
calling :meth:`Provider.close`, or the process dying) removes the token and the agent replans.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from ubitrack_agent.core import MEASUREMENT_TYPES, Measurement, encode
from ubitrack_agent.net.config import default_host_name
from ubitrack_agent.net.encodings import JSON
from ubitrack_agent.net.keys import KeySpace, validate_key_chunks
from ubitrack_agent.net.lifecycle import Closing
from ubitrack_agent.net.transport import LatestValuePublisher

SRG_TYPES = frozenset(cls.SRG_TYPE for cls in MEASUREMENT_TYPES.values())
MODES = ("push", "pull")


@dataclass(frozen=True)
class EdgeAnnouncement:
    """One measured edge ``source -> target`` a provider publishes.

    ``sigma`` is the expected RMS error (metres, or pixels for 2D edges), ``rate`` in Hz and
    ``latency`` in seconds; the planner's cost model uses them (``docs/planner.md``).
    """

    source: str
    target: str
    type: str
    static: bool = False
    mode: str = "push"
    name: str | None = None
    sigma: float | None = None
    rate: float | None = None
    latency: float | None = None

    def __post_init__(self) -> None:
        for frame in (self.source, self.target):
            validate_key_chunks(frame, single_chunk=True)
        if self.type not in SRG_TYPES:
            raise ValueError(f"edge type {self.type!r} is not one of {sorted(SRG_TYPES)}")
        if self.mode not in MODES:
            raise ValueError(f"edge mode {self.mode!r} is not push or pull")
        if self.name is None:
            object.__setattr__(self, "name", f"{self.source}_{self.target}")
        validate_key_chunks(self.name, single_chunk=True)
        for field_name in ("sigma", "rate", "latency"):
            value = getattr(self, field_name)
            if value is not None and not (isinstance(value, int | float) and value >= 0):
                raise ValueError(f"edge {self.name}: {field_name} must be a number >= 0")

    def as_json(self) -> dict[str, Any]:
        data: dict[str, Any] = {
            "name": self.name,
            "from": self.source,
            "to": self.target,
            "type": self.type,
            "static": self.static,
            "mode": self.mode,
        }
        for field_name in ("sigma", "rate", "latency"):
            if getattr(self, field_name) is not None:
                data[field_name] = getattr(self, field_name)
        return data


class Provider(Closing):
    """Announces a set of edges under ``provider_id`` and publishes their measurements.

    A context manager: ``with Provider(...) as provider:`` closes it on leaving the block.
    """

    def __init__(
        self,
        session: Any,
        keys: KeySpace,
        provider_id: str,
        edges: Iterable[EdgeAnnouncement],
        host: str | None = None,
    ) -> None:
        self.id = validate_key_chunks(provider_id, single_chunk=True)
        self.host = validate_key_chunks(host or default_host_name(), single_chunk=True)
        self.edges = {edge.name: edge for edge in edges}
        if not self.edges:
            raise ValueError("a provider needs at least one edge")
        self._fragment = json.dumps(
            {
                "provider": self.id,
                "host": self.host,
                "edges": [e.as_json() for e in self.edges.values()],
            }
        )
        self._publishers = {
            name: LatestValuePublisher(session, keys.measured(self.id, name)) for name in self.edges
        }
        self._queryable = session.declare_queryable(keys.fragment(self.id))
        self._thread = threading.Thread(target=self._serve_fragment, daemon=True)
        self._thread.start()
        self._token = session.liveliness().declare_token(keys.provider(self.id))
        self._closed = False

    def publish(self, edge_name: str, measurement: Measurement) -> None:
        """Publish one measurement of edge ``edge_name``; its type must match the edge's."""
        edge = self.edges.get(edge_name)
        if edge is None:
            raise KeyError(f"provider {self.id} announced no edge {edge_name!r}")
        if edge.type != measurement.SRG_TYPE:
            raise TypeError(f"edge {edge_name} is {edge.type}, got a {type(measurement).__name__}")
        self._publishers[edge_name].put(encode(measurement))

    def _serve_fragment(self) -> None:
        for query in self._queryable:
            with query:
                query.reply(query.key_expr, self._fragment, encoding=JSON)

    def close(self) -> None:
        """Withdraw the announcement (token first, so the agent replans at once); a second
        call does nothing."""
        if self._closed:
            return
        self._closed = True
        self._token.undeclare()
        self._queryable.undeclare()
        self._thread.join(timeout=1.0)
        for publisher in self._publishers.values():
            publisher.undeclare()
