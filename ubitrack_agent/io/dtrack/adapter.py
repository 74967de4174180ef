"""DTrack adapter: A.R.T. DTrack2/DTRACK3 ASCII UDP in, SRG edges and measurements out.

A :class:`~ubitrack_agent.io.adapter.SensorAdapter` for a real A.R.T. system (point DTrack's
output, *Settings -> Output*, at this host's port) or its simulator (:mod:`sim_trackers.sim_art`).

* **Edges.** Each mapped body id becomes a 6D edge ``<tracker> -> <frame>`` (dynamic, or static
  for a body fixed in the room, as the paper models ART->WT), each mapped single-marker id a 3D
  edge; edge names are ``<tracker>_<frame>``. Body ids count from 0 and marker ids from 1, as
  in DTrack's output (:mod:`ubitrack_agent.io.dtrack.format`).
* **Conversion.** Per datagram, every tracked body with a mapped id is published as an
  :class:`~ubitrack_agent.core.ErrorPose`: millimetres to metres, the column-wise rotation
  matrix to a quaternion, and as covariance the configured noise (``sigma_deg`` per axis about
  the body's own origin, ``sigma_mm`` per axis, independent) in the middleware's
  left-perturbation convention (:func:`ubitrack_agent.core.uncertainty.in_place_covariance`).
  A mapped marker becomes a :class:`~ubitrack_agent.core.Position3D` with covariance
  ``sigma_mm^2 I``. Each edge announces as ``sigma`` the expected error of that noise
  (:func:`~ubitrack_agent.core.uncertainty.expected_error`: a body's at a 1 m lever arm, so
  the planner weighs A.R.T.'s rotation noise too). A body or marker the datagram does not
  list, or lists with quality < 0 (the SDK's mark of an untracked item), is not published; an
  unmapped id is ignored and counted (``unmapped_body_<id>``, ``unmapped_marker_<id>``).
* **Timestamps.** ``"device"``: DTrack's ``ts`` (seconds since 00:00 UTC, the time of the IR
  flash) placed on the host's current UTC day, moved by a day when it is more than twelve hours
  off (datagrams around midnight), as VRPN does; this needs the controller's clock synchronised
  with the host's. ``"receive"`` (the default): the receive time.

The defaults below are those of the ``ubitrack dtrack`` command (``docs/simulators.md``).
"""

from __future__ import annotations

from collections.abc import Collection, Mapping

import numpy as np
from scipy.spatial.transform import Rotation

from ubitrack_agent.core import ErrorPose, Measurement, Position3D
from ubitrack_agent.core.uncertainty import (
    expected_error,
    in_place_covariance,
    isotropic_pose_covariance,
)
from ubitrack_agent.io.adapter import RejectedInput, SensorAdapter, TimestampPolicy
from ubitrack_agent.io.dtrack.format import DTrackFormatError, parse_frame, timestamp_from_ts
from ubitrack_agent.io.provider import EdgeAnnouncement

DEFAULT_PORT = 5000
"""UDP port: the one DTrack's documentation and examples use (the port is set in DTrack)."""

DEFAULT_TRACKER_FRAME = "ART"
"""The tracker's frame, named as in the paper's figure 1."""

DEFAULT_RATE_HZ = 60.0
"""Announced frame rate (the planner's cost model); set it to the controller's."""

DEFAULT_SIGMA_MM = 0.5
"""Position noise per axis (mm): a conservative figure for a calibrated room-size system, not
a manufacturer's; measure yours (e.g. the spread of a body at rest) and give that instead."""

DEFAULT_SIGMA_DEG = 0.1
"""Rotation noise per axis about the body's origin (degrees); same caveat as the position's."""


class DTrackAdapter(SensorAdapter):
    """Turns DTrack datagrams into measurements of the mapped bodies and markers (see the
    module docstring); ``ValueError`` for an inconsistent mapping."""

    device = "DTrack"

    def __init__(
        self,
        tracker: str,
        bodies: Mapping[int, str],
        static_bodies: Collection[str] = (),
        markers: Mapping[int, str] | None = None,
        sigma_mm: float = DEFAULT_SIGMA_MM,
        sigma_deg: float = DEFAULT_SIGMA_DEG,
        rate: float | None = DEFAULT_RATE_HZ,
        timestamps: TimestampPolicy = "receive",
    ) -> None:
        markers = markers or {}
        if not bodies and not markers:
            raise ValueError("no DTrack body or marker is mapped to a frame")
        if any(body_id < 0 for body_id in bodies) or any(marker_id < 1 for marker_id in markers):
            raise ValueError("DTrack body ids count from 0 and marker ids from 1")
        if unknown := sorted(set(static_bodies) - set(bodies.values())):
            raise ValueError(f"static body {unknown[0]!r} is not a mapped body's frame")
        if sigma_mm < 0 or sigma_deg < 0:
            raise ValueError("noise sigmas must be >= 0")
        sigma_m = sigma_mm / 1000.0
        pose_sigma = expected_error(isotropic_pose_covariance(np.radians(sigma_deg), sigma_m))
        edges = [
            EdgeAnnouncement(
                tracker,
                frame,
                "6D",
                static=frame in static_bodies,
                rate=None if frame in static_bodies else rate,
                sigma=pose_sigma,
            )
            for frame in bodies.values()
        ]
        edges += [
            EdgeAnnouncement(tracker, frame, "3D", rate=rate, sigma=sigma_m)
            for frame in markers.values()
        ]
        super().__init__(edges, timestamps)
        self.body_edges = {body_id: f"{tracker}_{frame}" for body_id, frame in bodies.items()}
        self.marker_edges = {
            marker_id: f"{tracker}_{frame}" for marker_id, frame in markers.items()
        }
        self.pose_covariance = isotropic_pose_covariance(np.radians(sigma_deg), sigma_m)
        self.position_covariance = np.eye(3) * sigma_m**2

    def convert(self, raw: bytes, received_ns: int) -> list[tuple[str, Measurement]]:
        try:
            frame = parse_frame(raw)
        except DTrackFormatError as exc:
            raise RejectedInput(f"malformed datagram: {exc}") from None
        device_ns = None
        if frame.timestamp_s is not None:
            device_ns = timestamp_from_ts(frame.timestamp_s, received_ns)
        stamp = self.stamp(device_ns, received_ns)
        measurements: list[tuple[str, Measurement]] = []
        for body in frame.bodies:
            edge = self._edge(self.body_edges, "body", body.id, body.quality)
            if edge is not None:
                rotation = Rotation.from_matrix(body.rotation).as_quat()
                translation = body.position_mm / 1000.0
                covariance = in_place_covariance(translation, self.pose_covariance)
                measurements.append((edge, ErrorPose(stamp, rotation, translation, covariance)))
        for marker in frame.markers:
            edge = self._edge(self.marker_edges, "marker", marker.id, marker.quality)
            if edge is not None:
                position = marker.position_mm / 1000.0
                measurements.append((edge, Position3D(stamp, position, self.position_covariance)))
        return measurements

    def _edge(self, edges: dict[int, str], kind: str, item_id: int, quality: float) -> str | None:
        if quality < 0:  # the SDK's mark of an untracked item
            return None
        edge = edges.get(item_id)
        if edge is None:
            self.ignore(f"unmapped_{kind}_{item_id}", f"{kind} id {item_id} is not mapped")
        return edge
