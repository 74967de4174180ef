"""DTrack adapter: A.R.T. DTrack2 ASCII UDP in, SRG edges and measurements out.

The same path serves the simulator (:mod:`sim_trackers.sim_art`) and a real A.R.T. system
(point DTrack's output at this host's port). Each configured body id becomes a 6D edge
``<tracker> -> <frame>`` (dynamic, or static for bodies fixed in the room, as the paper models
ART->WT), each configured single-marker id a 3D edge. Per datagram, every tracked body with a
configured id is published as an :class:`~ubitrack_agent.core.ErrorPose` (millimetres converted
to metres, the column-wise matrix to a quaternion) whose covariance is the configured noise
(``sigma_deg`` about the body's origin, ``sigma_mm`` per axis, independent), expressed in the
middleware's left-perturbation convention
(:func:`ubitrack_agent.core.uncertainty.in_place_covariance`); a body the datagram does not
list is simply not published.

Timestamps: with ``timestamps="ts"`` (the default) the DTrack ``ts`` field (seconds since 00:00
UTC, the time of the IR flash) is placed on the host's current UTC day, moved by a day when it
is more than twelve hours off (datagrams around midnight), as VRPN does; a datagram without
``ts`` falls back to the receive time. With ``timestamps="receive"`` the receive time
(``time.time_ns()``) is used always, for a controller whose clock is not synchronised with
this host.

Malformed datagrams are logged and counted (:attr:`DTrackAdapter.counters`), never fatal.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from collections import Counter
from typing import Literal, Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from ubitrack_agent.core import ErrorPose, Measurement, Position3D
from ubitrack_agent.core.uncertainty import in_place_covariance, isotropic_pose_covariance
from ubitrack_agent.io.dtrack_format import DTrackFormatError, parse_frame, timestamp_from_ts
from ubitrack_agent.io.provider import EdgeAnnouncement

log = logging.getLogger("ubitrack.dtrack")

TimestampPolicy = Literal["ts", "receive"]
MAX_DATAGRAM = 65_535


class Publisher(Protocol):
    """What the adapter needs of :class:`~ubitrack_agent.io.provider.Provider`."""

    def publish(self, edge_name: str, measurement: Measurement) -> None: ...


def announcements(
    tracker: str,
    bodies: dict[int, str],
    static_bodies: tuple[str, ...] = (),
    markers: dict[int, str] | None = None,
    rate: float | None = None,
    sigma_m: float | None = None,
) -> list[EdgeAnnouncement]:
    """The edges the adapter announces: one 6D edge per body, one 3D edge per marker."""
    edges = [
        EdgeAnnouncement(
            tracker,
            name,
            "6D",
            static=name in static_bodies,
            rate=None if name in static_bodies else rate,
            sigma=sigma_m,
        )
        for name in bodies.values()
    ]
    edges += [
        EdgeAnnouncement(tracker, name, "3D", rate=rate, sigma=sigma_m)
        for name in (markers or {}).values()
    ]
    return edges


class DTrackAdapter:
    """Turns DTrack datagrams into published measurements (see the module docstring)."""

    def __init__(
        self,
        publisher: Publisher,
        tracker: str,
        bodies: dict[int, str],
        markers: dict[int, str] | None = None,
        sigma_mm: float = 0.0,
        sigma_deg: float = 0.0,
        timestamps: TimestampPolicy = "ts",
    ) -> None:
        self.publisher = publisher
        self.body_edges = {body_id: f"{tracker}_{name}" for body_id, name in bodies.items()}
        self.marker_edges = {
            marker_id: f"{tracker}_{name}" for marker_id, name in (markers or {}).items()
        }
        self.pose_covariance = isotropic_pose_covariance(np.radians(sigma_deg), sigma_mm / 1000.0)
        self.position_covariance = np.eye(3) * (sigma_mm / 1000.0) ** 2
        self.timestamps = timestamps
        self.counters: Counter[str] = Counter()

    def handle(self, datagram: bytes, received_ns: int) -> None:
        """Parse one datagram and publish what it holds; bad input is logged and counted."""
        self.counters["datagrams"] += 1
        try:
            frame = parse_frame(datagram)
        except DTrackFormatError as exc:
            self.counters["malformed"] += 1
            log.warning(
                "malformed DTrack datagram (%d so far): %s", self.counters["malformed"], exc
            )
            return
        stamp = received_ns
        if self.timestamps == "ts" and frame.timestamp_s is not None:
            stamp = timestamp_from_ts(frame.timestamp_s, received_ns)
        for body in frame.bodies:
            edge = self._edge(self.body_edges, "body", body.id, body.quality)
            if edge is not None:
                rotation = Rotation.from_matrix(body.rotation).as_quat()
                translation = body.position_mm / 1000.0
                covariance = in_place_covariance(translation, self.pose_covariance)
                self._publish(edge, ErrorPose(stamp, rotation, translation, covariance))
        for marker in frame.markers:
            edge = self._edge(self.marker_edges, "marker", marker.id, marker.quality)
            if edge is not None:
                position = marker.position_mm / 1000.0
                self._publish(edge, Position3D(stamp, position, self.position_covariance))

    def _edge(self, edges: dict[int, str], kind: str, item_id: int, quality: float) -> str | None:
        if quality < 0:  # the SDK's mark of an untracked item
            return None
        edge = edges.get(item_id)
        if edge is None:
            key = f"unknown_{kind}_{item_id}"
            if not self.counters[key]:
                log.info("DTrack %s id %d is not mapped to a frame; ignored", kind, item_id)
            self.counters[key] += 1
        return edge

    def _publish(self, edge: str, measurement: Measurement) -> None:
        self.publisher.publish(edge, measurement)
        self.counters["published"] += 1


def open_socket(host: str, port: int) -> socket.socket:
    """A UDP socket bound to ``host:port`` with a short timeout, so the loop sees ``stop``."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind((host, port))
    sock.settimeout(0.1)
    return sock


def serve(
    sock: socket.socket,
    adapter: DTrackAdapter,
    stop: threading.Event,
    duration_s: float | None = None,
) -> None:
    """Receive datagrams on ``sock`` and hand them to ``adapter`` until stopped."""
    end = None if duration_s is None else time.monotonic() + duration_s
    while not stop.is_set() and (end is None or time.monotonic() < end):
        try:
            datagram = sock.recv(MAX_DATAGRAM)
        except TimeoutError:
            continue
        adapter.handle(datagram, time.time_ns())
