"""The calibration store: static edges served from a file, and new calibrations saved to it.

A real component (``ubitrack store FILE``), not a simulator: it reads a static-edges file
(:mod:`ubitrack_agent.io.static_edges`), announces every edge as a measured static edge of the
SRG and publishes its value, so every query (tracking C->A, a later static query for the same
relation) uses it; and it takes save requests for newly converged calibrations
(``ubitrack calibrate --save``), writes them to the file and serves them from then on.

* Each edge is announced by its own provider ``<store>.<edge name>`` (e.g. ``store.C_HT``):
  adding a calibration never withdraws the other edges, so the agent replans only what the new
  edge improves; a recalibration republishes the new value on the same data key, and every
  component reading it as a static input picks it up.
* A save request is a ``get`` on ``<root>/store/<name>`` (``KeySpace.store``) with one JSON
  object: ``{"from": "C", "to": "HT", "type": "6D", "value": {<value fields, as in the file>},
  "provenance": {<flat mapping>}}``. The store checks it as it checks a file entry, moves the
  previous value (if any) into the entry's ``history`` (newest first, at most
  ``static_edges.MAX_HISTORY``), writes the whole file atomically (temporary file, ``fsync``,
  rename, directory ``fsync``) and only then publishes the value and answers
  ``{"file": "<path>", "edge": "C_HT", "provider": "store.C_HT"}``. A refused request gets an
  error reply ``{"error": "refused", "reason": "..."}``, is logged (rate-limited) and counted.
  A ``kill -9`` at any moment leaves the old file or the new one, never a partial one.
* Each edge is announced with the ``sigma`` of its value's covariance
  (:meth:`~ubitrack_agent.io.static_edges.StaticEdge.served_announcement`), as every server of
  a static-edges file announces it and ``ubitrack plan`` reads it.
"""

from __future__ import annotations

import json
import logging
import os
import queue
import threading
import time
from collections import Counter
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

from ubitrack_agent.io.provider import Provider
from ubitrack_agent.io.static_edges import (
    MAX_HISTORY,
    StaticEdge,
    StaticEdgesError,
    parse_static_edges,
    read_static_edges,
    value_fields,
    write_static_edges,
)
from ubitrack_agent.net import logs
from ubitrack_agent.net.encodings import JSON
from ubitrack_agent.net.json_messages import MessageError, field, load_object
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.lifecycle import Closing

log = logging.getLogger("ubitrack.store")

MAX_REQUEST_BYTES = 64 * 1024
"""A save request holds one value: a few kilobytes."""


class CalibrationStore(Closing):
    """Serves the static edges of ``path`` under provider ids ``<name>.<edge>`` and saves new
    ones to it (see the module docstring). A missing file is a new, empty store (:attr:`new`;
    the file is created on the first save); a missing folder, where no save could ever write,
    is a ``FileNotFoundError``. Use as a context manager, or call :meth:`close`."""

    def __init__(
        self,
        session: Any,
        keys: KeySpace,
        path: str | os.PathLike[str],
        name: str,
        host: str | None = None,
    ):
        self.path = Path(path)
        self.host = host
        self.name = name
        self.counters: Counter[str] = Counter()
        self._session = session
        self._keys = keys
        self.edges: dict[str, StaticEdge] = {}
        if not self.path.parent.is_dir():
            raise FileNotFoundError(
                f"{self.path.parent} is not a folder: the store could never save {self.path}"
            )
        self.new = not self.path.exists()
        """Whether ``path`` did not exist: a new, empty store (a mistyped path shows here)."""
        if not self.new:
            _, edges = read_static_edges(self.path, time.time_ns())
            self.edges = {edge.announcement.name: edge for edge in edges}
        self._providers: dict[str, Provider] = {}
        for edge in self.edges.values():
            self._serve(edge)
        self._closed = False
        self._requests: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._queryable = session.declare_queryable(
            keys.store(name), lambda query: self._requests.put(query)
        )
        self._thread = threading.Thread(target=self._handle_requests, daemon=True)
        self._thread.start()

    def provider_id(self, edge: StaticEdge) -> str:
        return f"{self.name}.{edge.announcement.name}"

    def _serve(self, edge: StaticEdge) -> None:
        """Announce ``edge`` (once) and publish its value."""
        name = edge.announcement.name
        if name not in self._providers:
            self._providers[name] = Provider(
                self._session,
                self._keys,
                self.provider_id(edge),
                [edge.served_announcement()],
                self.host,
            )
        self._providers[name].publish(name, replace(edge.value, timestamp_ns=time.time_ns()))

    def save(self, request: Mapping[str, Any]) -> StaticEdge:
        """Check a save request, write the file with the new value, then serve it; raises
        :class:`StaticEdgesError` or :class:`MessageError` for a request it refuses."""
        entry = {key: request.get(key) for key in ("from", "to", "type")}
        value = field(request, "value", dict)
        provenance = field(request, "provenance", dict, optional=True) or {}
        unknown = sorted(set(request) - {"from", "to", "type", "value", "provenance"})
        if unknown:
            raise MessageError("malformed_request", f"unknown fields {unknown}")
        document = {"provider": self.name, "edges": [{**entry, **value, "provenance": provenance}]}
        _, (edge,) = parse_static_edges(document, time.time_ns(), "save request")
        name = edge.announcement.name
        previous = self.edges.get(name)
        if previous is not None:
            earlier = {**value_fields(previous.value), "provenance": previous.provenance or {}}
            history = (earlier, *previous.history)[:MAX_HISTORY]
            edge = replace(edge, history=history)
        edges = {**self.edges, name: edge}
        write_static_edges(self.path, self.name, edges.values())  # durable before it is served
        self.edges = edges
        self._serve(edge)
        self.counters["saved"] += 1
        log.info("saved %s to %s", name, self.path)
        return edge

    def _handle_requests(self) -> None:
        """Answers save requests on this thread (never in a zenoh callback)."""
        while (query := self._requests.get()) is not None:
            with query:
                try:
                    payload = query.payload.to_bytes() if query.payload is not None else None
                    edge = self.save(load_object(payload, MAX_REQUEST_BYTES))
                except (MessageError, StaticEdgesError, ValueError, OSError) as exc:
                    self.counters["refused"] += 1
                    if logs.rate_limited(self.counters["refused"]):
                        log.warning("refused a save request: %s", exc)
                    reason = json.dumps({"error": "refused", "reason": str(exc)})
                    query.reply_err(reason)
                    continue
                answer = {
                    "file": str(self.path.resolve()),
                    "edge": edge.announcement.name,
                    "provider": self.provider_id(edge),
                }
                query.reply(query.key_expr, json.dumps(answer), encoding=JSON)

    def close(self) -> None:
        """Stop taking requests and withdraw every edge; a second call does nothing."""
        if self._closed:
            return
        self._closed = True
        self._queryable.undeclare()
        self._requests.put(None)
        self._thread.join(timeout=2.0)
        for provider in self._providers.values():
            provider.close()
