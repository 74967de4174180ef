"""DTrack adapter: A.R.T. DTrack2/DTRACK3 ASCII UDP in, SRG edges and measurements out.

A :class:`~ubitrack_agent.io.adapter.SensorAdapter` for a real A.R.T. system (point DTrack's
output, *Settings -> Output*, at this host's port) or its simulator
(:mod:`ubitrack_agent.sim_trackers.sim_art`).

* **Edges.** Each mapped body id becomes a 6D edge ``<tracker> -> <frame>`` (dynamic, or static
  for a body fixed in the room, as the paper models ART->WT), and so does each mapped
  measurement-tool id and Flystick id (dynamic); each mapped single-marker id becomes a 3D edge;
  edge names are ``<tracker>_<frame>``. Body, tool and Flystick ids count from 0 and marker
  ids from 1, as in DTrack's output (:mod:`ubitrack_agent.io.dtrack.format`).
* **Which lines.** Bodies come from ``6d`` and from ``6di`` (hybrid optical-inertial bodies),
  both under the body mapping, since DTrack numbers them alike; a body listed in both lines
  of one datagram is published once, with the ``6di`` (fused) pose. Tools come from ``6dmt``
  or ``6dmt2``, Flysticks from ``6df`` or ``6df2``: only their poses (buttons, joysticks and
  the tip radius are not published). Any other line type (``gl``, ``6dj``, ``6dcov``, ``st``,
  an unknown one) is skipped, warned about once per type and counted (``line_<type>``).
* **Conversion.** Per datagram, every tracked item with a mapped id is published as an
  :class:`~ubitrack_agent.core.ErrorPose`: millimetres to metres, the column-wise rotation
  matrix to a quaternion, and as covariance the configured noise (``sigma_deg`` per axis about
  the item's own origin, ``sigma_mm`` per axis, independent) in the middleware's
  left-perturbation convention (:func:`ubitrack_agent.core.uncertainty.in_place_covariance`);
  for a ``6dmt2`` tool, DTrack's own 3x3 position covariance (mm^2, converted to m^2) replaces
  ``sigma_mm`` when it is positive definite (a zero one would claim a perfect position).
  A mapped marker becomes a :class:`~ubitrack_agent.core.Position3D` with covariance
  ``sigma_mm^2 I``. Each edge announces as ``sigma`` the expected error of the configured
  noise (:func:`~ubitrack_agent.core.uncertainty.expected_error`: a pose's at a 1 m lever arm,
  so the planner weighs A.R.T.'s rotation noise too). An item the datagram does not list, or
  lists as untracked (the parser leaves those out), is not published, and reported missed
  (each datagram is a whole frame, :attr:`~ubitrack_agent.io.adapter.SensorAdapter.whole_frames`:
  its edge's token is withdrawn in the second such frame in a row, ``io.flowing``); an
  unmapped id is
  ignored and counted (``unmapped_body_<id>``, ``unmapped_tool_<id>``,
  ``unmapped_flystick_<id>``, ``unmapped_marker_<id>``).
* **Timestamps.** ``"device"``: DTRACK3's ``ts2`` (the measurement's Unix time) when it is
  within 0.1 s of the receive time, otherwise the receive time minus ``ts2``'s latency (the
  controller's clock is not synchronised; warned once, counted as ``ts2_clock_off``), as VRPN
  does; without ``ts2``, DTrack's ``ts`` (seconds since 00:00 UTC, the time of the IR flash)
  placed on the host's current UTC day, moved by a day when it is more than twelve hours off
  (datagrams around midnight), as VRPN does, which needs the controller's clock synchronised
  with the host's. ``"receive"`` (the default): the receive time.

The defaults below are those of the ``ubitrack dtrack`` command (``docs/simulators.md``).
"""

from __future__ import annotations

import logging
from collections.abc import Collection, Mapping

import numpy as np
from scipy.spatial.transform import Rotation

from ubitrack_agent.core import ErrorPose, Measurement, MeasurementError, Position3D
from ubitrack_agent.core.uncertainty import (
    in_place_covariance,
    isotropic_pose_covariance,
)
from ubitrack_agent.io.adapter import RejectedInput, SensorAdapter, TimestampPolicy, pose_edges
from ubitrack_agent.io.dtrack.format import (
    UNSUPPORTED_LINES,
    Body6D,
    DTrackFormatError,
    DTrackFrame,
    parse_frame,
    timestamp_from_ts,
)
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


TS2_CLOCK_TOLERANCE_NS = 100_000_000
"""How far ``ts2`` may be from the receive time to be used as it is (VRPN's 0.1 s)."""

MAX_LINE_TYPES = 32
"""Skipped line types counted each under its own name; further ones share one counter (a
bound on the counters a stream of odd datagrams can create)."""


class DTrackAdapter(SensorAdapter[bytes]):
    """Turns DTrack datagrams into measurements of the mapped bodies, measurement tools,
    Flysticks and markers (see the module docstring); ``ValueError`` for an inconsistent
    mapping."""

    device = "DTrack"
    whole_frames = True

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
        tools: Mapping[int, str] | None = None,
        flysticks: Mapping[int, str] | None = None,
    ) -> None:
        markers, tools, flysticks = markers or {}, tools or {}, flysticks or {}
        poses = [*bodies.values(), *tools.values(), *flysticks.values()]
        if not poses and not markers:
            raise ValueError("no DTrack body, tool, Flystick or marker is mapped to a frame")
        if any(i < 0 for i in (*bodies, *tools, *flysticks)) or any(i < 1 for i in markers):
            raise ValueError(
                "DTrack body, tool and Flystick ids count from 0 and marker ids from 1"
            )
        if unknown := sorted(set(static_bodies) - set(bodies.values())):
            raise ValueError(f"static body {unknown[0]!r} is not a mapped body's frame")
        if sigma_mm < 0 or sigma_deg < 0:
            raise ValueError("noise sigmas must be >= 0")
        sigma_m = sigma_mm / 1000.0
        self.pose_covariance = isotropic_pose_covariance(np.radians(sigma_deg), sigma_m)
        edges = pose_edges(tracker, poses, static_bodies, rate, self.pose_covariance)
        edges += [
            EdgeAnnouncement(tracker, frame, "3D", rate=rate, sigma=sigma_m)
            for frame in markers.values()
        ]
        super().__init__(edges, timestamps)

        def edge_names(mapping: Mapping[int, str]) -> dict[int, str]:
            return {item_id: f"{tracker}_{frame}" for item_id, frame in mapping.items()}

        self.body_edges = edge_names(bodies)
        self.tool_edges = edge_names(tools)
        self.flystick_edges = edge_names(flysticks)
        self.marker_edges = edge_names(markers)
        self.position_covariance = np.eye(3) * sigma_m**2
        self._line_types: set[str] = set()

    def convert(self, raw: bytes, received_ns: int) -> list[tuple[str, Measurement]]:
        try:
            frame = parse_frame(raw)
        except DTrackFormatError as exc:
            raise RejectedInput(f"malformed datagram: {exc}") from None
        for line_id in frame.skipped_lines:
            self._skip_line(line_id)
        device_ns = self._device_ns(frame, received_ns) if self.timestamps == "device" else None
        try:
            return self._measurements(frame, self.stamp(device_ns, received_ns))
        except MeasurementError as exc:  # e.g. a position so large its covariance overflows
            raise RejectedInput(f"datagram out of range: {exc}") from None

    def _measurements(self, frame: DTrackFrame, stamp: int) -> list[tuple[str, Measurement]]:
        """The mapped items of ``frame``, stamped ``stamp``."""
        # A hybrid body's fused pose replaces its optical one when both lines list it.
        bodies = {body.id: body for body in (*frame.bodies, *frame.hybrid_bodies)}
        measurements: list[tuple[str, Measurement]] = [
            (edge, self._pose(item, stamp))
            for items, edges, kind in (
                (bodies.values(), self.body_edges, "body"),
                (frame.tools, self.tool_edges, "tool"),
                (frame.flysticks, self.flystick_edges, "Flystick"),
            )
            for item in items
            if (edge := self._edge(edges, kind, item.id)) is not None
        ]
        for marker in frame.markers:
            edge = self._edge(self.marker_edges, "marker", marker.id)
            if edge is not None:
                position = marker.position_mm / 1000.0
                measurements.append((edge, Position3D(stamp, position, self.position_covariance)))
        return measurements

    def _pose(self, item: Body6D, stamp: int) -> ErrorPose:
        """An item's pose in metres with its covariance: the configured noise, with a
        ``6dmt2`` tool's own position covariance in place of ``sigma_mm`` when it is positive
        definite (a zero one would claim a perfect position)."""
        translation = item.position_mm / 1000.0
        covariance = self.pose_covariance.copy()
        reported = item.position_covariance_mm2
        if reported is not None and np.linalg.eigvalsh(reported).min() > 0:
            covariance[3:, 3:] = reported / 1e6
        rotation = Rotation.from_matrix(item.rotation).as_quat()
        return ErrorPose(stamp, rotation, translation, in_place_covariance(translation, covariance))

    def _device_ns(self, frame: DTrackFrame, received_ns: int) -> int | None:
        """The measurement time the datagram gives (Unix ns), ``None`` without one: ``ts2``
        if it is within :data:`TS2_CLOCK_TOLERANCE_NS` of the receive time, else the receive
        time minus ``ts2``'s latency (the controller's clock is off; VRPN's rule); without
        ``ts2``, ``ts`` on the host's UTC day."""
        if frame.unix_time is not None:
            if abs(frame.unix_time.unix_ns - received_ns) <= TS2_CLOCK_TOLERANCE_NS:
                return frame.unix_time.unix_ns
            self.ignore(
                "ts2_clock_off",
                "ts2's time, more than 0.1 s off this host's clock (the receive time minus "
                "ts2's latency is used instead)",
                logging.WARNING,
            )
            return received_ns - frame.unix_time.latency_ns
        if frame.timestamp_s is not None:
            return timestamp_from_ts(frame.timestamp_s, received_ns)
        return None

    def _skip_line(self, line_id: str) -> None:
        """Count a skipped line type, warning once per type (:data:`MAX_LINE_TYPES` of them)."""
        if line_id not in self._line_types and len(self._line_types) >= MAX_LINE_TYPES:
            self.ignore("line_other", "more line types are not supported", logging.WARNING)
            return
        self._line_types.add(line_id)
        kind = "unsupported" if line_id in UNSUPPORTED_LINES else "unknown"
        self.ignore(f"line_{line_id}", f"{kind} line type {line_id!r}", logging.WARNING)

    def _edge(self, edges: dict[int, str], kind: str, item_id: int) -> str | None:
        edge = edges.get(item_id)
        if edge is None:
            self.ignore(f"unmapped_{kind.lower()}_{item_id}", f"{kind} id {item_id} is not mapped")
        return edge
