"""The 3D view's zenoh side: the recent samples of every live 6D and 3D relation.

From each status of the agent it follows the data keys of the SRG's measured 6D and 3D edges
(``<root>/data/<edge id>``) and the outputs of the running components that derive a 6D or 3D
relation (their ``derives`` and ``outputs``); a plain subscriber per key queues its payloads
(zenoh's callback only stores the bytes, at most :data:`~.align.HISTORY` per key), and a
``get`` asks a static edge's provider for its current value (a static edge is published when it
changes: :class:`~ubitrack_agent.net.transport.LatestValuePublisher`). :meth:`FrameWatch.frames`
decodes the payloads that came since it last ran into each relation's recent samples, evaluates
every relation at one display time (:func:`~.align.align`: time-aligned, not each relation's
latest sample) and places the frames (:func:`~.frames.place`) on the thread that asks, so the
page gets the newest poses at its own rate, not the poll's.

Like the rest of the view it declares no query: watching changes no plan. A component's output
inside a container is handed on as an object and put on the network only while someone
subscribes (``not_sent`` in its counters), so watching it costs its worker the encoding.
Keys come from the network: only keys under this view's ``<root>/data/`` are followed, at most
:data:`MAX_KEYS`.
"""

from __future__ import annotations

import logging
import threading
from collections import Counter, deque
from collections.abc import Iterable, Mapping
from typing import Any

from ubitrack_agent.commands.view.align import HISTORY, Recent, align
from ubitrack_agent.commands.view.frames import LiveRelation, place, srg_frames, tracker_frame
from ubitrack_agent.core.codec import decode
from ubitrack_agent.core.errors import MeasurementError
from ubitrack_agent.net import logs
from ubitrack_agent.net.keys import KeySpace, validate_key_chunks

log = logging.getLogger("ubitrack.view")

MAX_KEYS = 256
"""Most keys the 3D view follows (one subscriber each), whatever a status lists."""

SPATIAL = ("6D", "3D")
"""Relation types that place a frame."""

GET_TIMEOUT_S = 1.0

Followed = tuple[str, str, bool, str, bool]
"""A followed relation: ``(source, target, derived, name, static)``."""


def spatial_keys(status: dict[str, Any], keys: KeySpace) -> dict[str, Followed]:
    """The keys of ``status``'s live 6D and 3D relations: ``key -> (source, target, derived,
    name, static)`` for each measured edge (named by its id; static as the SRG says) and each
    output of a component deriving one such relation (named by the instance; static when all
    its inputs are); keys
    outside ``<root>/data/`` or malformed are left out, and more than :data:`MAX_KEYS`.
    O(edges + components)."""
    wanted: dict[str, Followed] = {}
    data = f"{keys.root}/data/"

    def add(key: Any, source: Any, target: Any, derived: bool, name: str, static: bool) -> None:
        if len(wanted) >= MAX_KEYS or not all(isinstance(s, str) for s in (key, source, target)):
            return
        try:
            validate_key_chunks(key)
        except ValueError:
            return
        if key.startswith(data):
            wanted[key] = (source, target, derived, name, static)

    for edge in _list(status.get("srg")):
        spatial = isinstance(edge, dict) and edge.get("type") in SPATIAL
        if spatial and isinstance(edge.get("id"), str):
            try:
                key = keys.data(edge["id"])
            except ValueError:
                continue
            add(
                key, edge.get("from"), edge.get("to"), False, edge["id"], edge.get("static") is True
            )
    components = status.get("components")
    for instance, component in (components if isinstance(components, dict) else {}).items():
        if not isinstance(component, dict):
            continue
        derives = [d for d in _list(component.get("derives")) if _triple(d)]
        outputs = component.get("outputs")
        if len(derives) != 1 or derives[0][2] not in SPATIAL or not isinstance(outputs, dict):
            continue
        inputs = _list(component.get("inputs"))
        static = bool(inputs) and all(
            isinstance(i, dict) and i.get("static") is True for i in inputs
        )
        for key in outputs.values():
            add(key, derives[0][0], derives[0][1], True, str(instance), static)
    return wanted


def _triple(value: Any) -> bool:
    return isinstance(value, list) and len(value) == 3


def _list(value: Any) -> list[Any]:
    return value if isinstance(value, list) else []


def take(
    recent: dict[str, Recent],
    wanted: Mapping[str, Followed],
    payloads: Mapping[str, Iterable[bytes]],
    counters: Counter[str],
) -> None:
    """Decode ``payloads`` (by key) into ``recent``, each relation's recent samples (static as
    ``wanted`` says); keys no longer ``wanted`` are dropped. A payload that is no measurement
    is counted (``undecodable_samples``) and left out. O(payloads) decodes."""
    for key in [key for key in recent if key not in wanted]:
        del recent[key]
    for key, queued in payloads.items():
        if key not in wanted:
            continue
        static = wanted[key][4]
        if key not in recent or recent[key].static != static:
            recent[key] = Recent(static)
        for payload in queued:
            try:
                recent[key].add(decode(payload))
            except MeasurementError as exc:
                logs.count_problem(counters, "undecodable_samples", log, "%s: %s", key, exc)


def frames_from(
    srg: list[Any],
    wanted: Mapping[str, Followed],
    recent: Mapping[str, Recent],
    root: str | None,
) -> dict[str, Any]:
    """The frames of ``srg`` (a status's) placed relative to ``root`` (default:
    :func:`~.frames.tracker_frame`) by the ``recent`` samples of each key :func:`spatial_keys`
    gave (``wanted``), every relation evaluated at one display time (:func:`~.align.align`),
    with the frames the SRG knows, the default root, the display time (``display_time_ns``),
    how far it is behind the newest sample (``behind_ms``) and how each relation was taken
    (``relations``: name -> mode and skew); ``{"error": why, "known": frames}`` for a root the
    SRG does not know, or none known yet. O(keys log history) and one :func:`~.frames.place`."""
    known = srg_frames(srg)
    default = tracker_frame(srg)
    chosen = root if root is not None else default
    if not known:
        return {"error": "no frames yet: no agent's status has named an SRG edge", "known": []}
    if chosen is None or chosen not in known:
        return {"error": f"no frame {str(chosen)[:100]!r} in the SRG", "known": known}
    alignment = align({key: samples for key, samples in recent.items() if key in wanted})
    relations = []
    taken = {}
    for key, aligned in alignment.relations.items():
        source, target, derived, name, _ = wanted[key]
        relations.append(
            LiveRelation(source, target, aligned.value, derived, name, aligned.skew_ns)
        )
        taken[name] = {"mode": aligned.mode, "skew_ms": round(aligned.skew_ns / 1e6, 3)}
    behind = None
    if alignment.display_ns is not None and alignment.newest_ns is not None:
        behind = round((alignment.newest_ns - alignment.display_ns) / 1e6, 3)
    return {
        **place(known, relations, chosen),
        "known": known,
        "default_root": default,
        "display_time_ns": alignment.display_ns,
        "behind_ms": behind,
        "relations": taken,
    }


class FrameWatch:
    """Follows the live spatial relations of the latest status; :meth:`frames` places them."""

    def __init__(self, session: Any, keys: KeySpace, counters: Counter[str]) -> None:
        self.session = session
        self.keys = keys
        self.counters = counters
        self._lock = threading.Lock()  # what zenoh's callbacks touch, and what follow() sets
        self._wanted: dict[str, Followed] = {}
        self._queued: dict[str, deque[bytes]] = {}
        self._heard: set[str] = set()
        self._subscribers: dict[str, Any] = {}
        self._srg: list[Any] = []
        self._placing = threading.Lock()  # the decoded samples, for one frames() at a time
        self._recent: dict[str, Recent] = {}

    def follow(self, status: dict[str, Any]) -> None:
        """Follow exactly the spatial relations of ``status`` (:func:`spatial_keys`).
        Subscribers are declared and undeclared outside the lock their callbacks take."""
        wanted = spatial_keys(status, self.keys)
        with self._lock:
            self._srg = _list(status.get("srg"))
            self._wanted = wanted
            gone = [key for key in self._subscribers if key not in wanted]
            dropped = [self._subscribers.pop(key) for key in gone]
            for key in gone:
                self._queued.pop(key, None)
                self._heard.discard(key)
            new = [key for key in wanted if key not in self._subscribers]
        for subscriber in dropped:
            subscriber.undeclare()
        declared = {
            key: self.session.declare_subscriber(
                key, lambda sample, key=key: self._store(key, sample.payload.to_bytes())
            )
            for key in new
        }
        with self._lock:
            self._subscribers.update(declared)
            unanswered = [key for key in wanted if key not in self._heard]
        for key in unanswered:  # a static edge's value, or a dynamic one's before it moves
            self.session.get(key, handler=self._replied, timeout=GET_TIMEOUT_S)

    def _store(self, key: str, payload: bytes) -> None:
        # on zenoh's thread: queue the bytes, nothing more
        with self._lock:
            if key in self._subscribers:
                self._queued.setdefault(key, deque(maxlen=HISTORY)).append(payload)
                self._heard.add(key)

    def _replied(self, reply: Any) -> None:
        if reply.ok is not None:
            self._store(str(reply.ok.key_expr), reply.ok.payload.to_bytes())

    def frames(self, root: str | None) -> dict[str, Any]:
        """:func:`frames_from` the latest status and the samples come since the last call."""
        with self._lock:
            queued, self._queued = self._queued, {}
            wanted = dict(self._wanted)
            srg = list(self._srg)
        with self._placing:
            take(self._recent, wanted, queued, self.counters)
            return frames_from(srg, wanted, self._recent, root)

    def close(self) -> None:
        with self._lock:
            subscribers = list(self._subscribers.values())
            self._subscribers.clear()
        for subscriber in subscribers:
            subscriber.undeclare()
