"""NatNet adapter: OptiTrack Motive's NatNet packets in, SRG edges and measurements out.

A :class:`~ubitrack_agent.io.adapter.SensorAdapter` for a real Motive (Streaming pane: enable
"Broadcast Frame Data", rigid bodies on) or its simulator
(:mod:`ubitrack_agent.sim_trackers.sim_natnet`).
It handles every packet the server sends on either channel (:mod:`.format`); the sockets,
connect and keep-alive live in :mod:`.link`.

* **Edges.** Each mapped rigid body becomes a 6D edge ``<tracker> -> <frame>`` (dynamic, or
  static for a body fixed in the room), named ``<tracker>_<frame>``, as ``ubitrack dtrack``
  does. A body is mapped by its name in Motive (``bodies``; the name comes from the model
  definitions, ``NAT_MODELDEF``) or by its streaming id (``body_ids``).
* **Version negotiation.** ``NAT_SERVERINFO`` (the reply to ``NAT_CONNECT``) gives the NatNet
  version the server streams, which fixes the layout of its model definitions and frames; a
  frame or model definition arriving before it is ignored and counted
  (``before_server_info``), unless a version was given (``version``, for a multicast stream
  whose command channel cannot be reached). A version this adapter does not parse (2.x, 5.x)
  is counted (``unsupported_version``) and nothing is parsed.
* **Naming.** Each ``NAT_MODELDEF`` replaces the id -> name table. A frame listing an id
  with no name yet, or flagging "tracked models changed", sets :attr:`NatNetAdapter.wants_models`
  so the link asks for the model definitions again (rate-limited there).
* **Conversion.** Per frame, every rigid body with a mapped id, Motive's tracking-valid flag
  set (else counted ``untracked_<frame>``) and a mean marker error within
  ``max_marker_error_mm`` (else counted ``marker_error_<frame>``) is published as an
  :class:`~ubitrack_agent.core.ErrorPose`: metres and quaternions as streamed, with the
  configured noise as covariance (``sigma_deg`` per axis about the body's origin, ``sigma_mm``
  per axis; :func:`ubitrack_agent.core.uncertainty.in_place_covariance`), as the DTrack adapter
  does. An id with no mapping is ignored and counted (``unmapped_body_<id>``, at most
  :data:`MAX_UNMAPPED` counters; ``before_model_definitions`` for an id not yet named while
  bodies are mapped by name).
* **Timestamps.** ``"device"``: the receive time minus NatNet's own latency, the transmit
  minus the camera mid-exposure timestamp in ticks of the server's high-resolution clock
  (frequency from ``NAT_SERVERINFO``), which needs no clock synchronisation; without a usable
  latency (no frequency, zero stamps, negative or over :data:`MAX_LATENCY_NS`) the receive
  time, counted (``latency_unusable``). The 4.1+ precision (PTP) timestamp is parsed but not
  used: the SDK does not document its fractional unit. ``"receive"`` (the default): the
  receive time.

Each packet costs O(b + n) for its b bytes and n rigid bodies; the name table is O(bodies).
"""

from __future__ import annotations

import logging
from collections.abc import Collection, Mapping

import numpy as np

from ubitrack_agent.core import ErrorPose, Measurement, MeasurementError
from ubitrack_agent.core.uncertainty import (
    in_place_covariance,
    isotropic_pose_covariance,
)
from ubitrack_agent.io.adapter import RejectedInput, SensorAdapter, TimestampPolicy, pose_edges
from ubitrack_agent.io.natnet import format as natnet
from ubitrack_agent.io.natnet.format import NatNetFormatError, NatNetVersion
from ubitrack_agent.net.logs import rate_limited

DEFAULT_COMMAND_PORT = 1510
DEFAULT_DATA_PORT = 1511
DEFAULT_MULTICAST_GROUP = "239.255.42.99"
"""Motive's defaults (Streaming pane)."""

DEFAULT_TRACKER_FRAME = "OptiTrack"
DEFAULT_RATE_HZ = 120.0
"""Announced frame rate (the planner's cost model); set it to Motive's."""

DEFAULT_SIGMA_MM = 0.5
DEFAULT_SIGMA_DEG = 0.1
"""Noise per axis: a conservative guess for a calibrated room, not a manufacturer's figure
(as ``ubitrack dtrack``'s); measure yours."""

MAX_LATENCY_NS = 1_000_000_000
"""Longest NatNet latency believed (transmit minus mid-exposure); beyond, the receive time."""

MAX_UNMAPPED = 64
"""Unmapped ids counted each under its own name; further ones share one counter."""

_MESSAGES = {
    natnet.NAT_SERVERINFO: "server_info",
    natnet.NAT_MODELDEF: "model_definitions",
    natnet.NAT_FRAMEOFDATA: "frame",
}


class NatNetAdapter(SensorAdapter[bytes]):
    """Turns NatNet packets into measurements of the mapped rigid bodies (see the module
    docstring); ``ValueError`` for an inconsistent mapping."""

    device = "NatNet"

    def __init__(
        self,
        tracker: str,
        bodies: Mapping[str, str] | None = None,
        body_ids: Mapping[int, str] | None = None,
        static_bodies: Collection[str] = (),
        sigma_mm: float = DEFAULT_SIGMA_MM,
        sigma_deg: float = DEFAULT_SIGMA_DEG,
        rate: float | None = DEFAULT_RATE_HZ,
        timestamps: TimestampPolicy = "receive",
        max_marker_error_mm: float | None = None,
        version: NatNetVersion | None = None,
    ) -> None:
        bodies, body_ids = dict(bodies or {}), dict(body_ids or {})
        frames = [*bodies.values(), *body_ids.values()]
        if not frames:
            raise ValueError("no NatNet rigid body is mapped to a frame")
        if unknown := sorted(set(static_bodies) - set(frames)):
            raise ValueError(f"static body {unknown[0]!r} is not a mapped body's frame")
        if sigma_mm < 0 or sigma_deg < 0:
            raise ValueError("noise sigmas must be >= 0")
        if max_marker_error_mm is not None and max_marker_error_mm <= 0:
            raise ValueError("the largest mean marker error must be > 0 mm")
        if version is not None and not natnet.supported(version):
            raise ValueError(f"NatNet {version} is not supported (3.0 to 4.x are)")
        self.pose_covariance = isotropic_pose_covariance(np.radians(sigma_deg), sigma_mm / 1000.0)
        super().__init__(
            pose_edges(tracker, frames, static_bodies, rate, self.pose_covariance), timestamps
        )
        self.tracker = tracker
        self.by_name = {name: f"{tracker}_{frame}" for name, frame in bodies.items()}
        self.by_id = {body_id: f"{tracker}_{frame}" for body_id, frame in body_ids.items()}
        self.max_marker_error_m = None if max_marker_error_mm is None else max_marker_error_mm / 1e3
        self.fixed_version = version
        self.server: natnet.ServerInfo | None = None
        self.names: dict[int, str] = {}
        """Motive's rigid-body names by streaming id, from the last model definitions."""
        self.wants_models = True
        """Whether the model definitions should be asked for (again)."""
        self._edges_by_id = dict(self.by_id)
        self._unmapped_ids: set[int] = set()

    @property
    def version(self) -> NatNetVersion | None:
        """The version packets are parsed at: the server's, else the one given."""
        return self.server.natnet_version if self.server else self.fixed_version

    def convert(self, raw: bytes, received_ns: int) -> list[tuple[str, Measurement]]:
        try:
            message_id, payload = natnet.split_packet(raw)
        except NatNetFormatError as exc:
            raise self._reject("packet", exc) from None
        kind = _MESSAGES.get(message_id)
        if kind is None:
            self.ignore(
                f"message_{message_id}" if message_id < 256 else "message_other",
                f"message {message_id} carries nothing to publish",
            )
            return []
        try:
            if message_id == natnet.NAT_SERVERINFO:
                self._server_info(natnet.parse_server_info(payload))
                return []
            version = self.version
            if version is None:
                self.ignore("before_server_info", f"a {kind} before the server's version")
                return []
            if not natnet.supported(version):
                self.ignore(
                    "unsupported_version", f"NatNet {version} is not supported", logging.WARNING
                )
                return []
            if message_id == natnet.NAT_MODELDEF:
                self._models(natnet.parse_model_definitions(payload, version))
                return []
            frame = natnet.parse_frame(payload, version)
        except NatNetFormatError as exc:
            raise self._reject(kind, exc) from None
        try:
            return self._measurements(frame, received_ns)
        except MeasurementError as exc:  # e.g. a zero quaternion on a tracked body
            raise self._reject(kind, exc) from None

    def _reject(self, kind: str, exc: Exception) -> RejectedInput:
        """A typed rejection: counted under ``rejected_<kind>`` here, ``rejected`` by the base."""
        self.counters[f"rejected_{kind}"] += 1
        return RejectedInput(f"malformed {kind}: {exc}")

    def _server_info(self, info: natnet.ServerInfo) -> None:
        """Take the server's description; a new one is counted (``server_info_changes``) and
        logged rate-limited (a spoofed flood of them cannot flood the log)."""
        if info != self.server:
            self.counters["server_info_changes"] += 1
            if rate_limited(self.counters["server_info_changes"]):
                supported = natnet.supported(info.natnet_version)
                logging.getLogger("ubitrack.adapter").log(
                    logging.INFO if supported else logging.WARNING,
                    "NatNet: server %s %s streams NatNet %s",
                    info.application,
                    info.application_version,
                    info.natnet_version,
                )
        self.server = info

    def _models(self, models: natnet.ModelDefinitions) -> None:
        self.names = {body.id: body.name for body in models.rigid_bodies}
        self._edges_by_id = dict(self.by_id)
        for body_id, name in self.names.items():
            if name in self.by_name and body_id not in self.by_id:
                self._edges_by_id[body_id] = self.by_name[name]
        self.counters["model_definitions"] += 1
        self.wants_models = False
        if missing := sorted(set(self.by_name) - set(self.names.values())):
            self.ignore(
                "missing_bodies", f"Motive lists no rigid body named {missing}", logging.WARNING
            )

    def _measurements(self, frame: natnet.Frame, received_ns: int) -> list[tuple[str, Measurement]]:
        if frame.models_changed:
            self.wants_models = True
        stamp = self.stamp(self._device_ns(frame, received_ns), received_ns)
        measurements: list[tuple[str, Measurement]] = []
        for body in frame.rigid_bodies:
            edge = self._edges_by_id.get(body.id)
            if edge is None:
                self._unmapped(body.id)
                continue
            if not body.tracking_valid:
                self.counters[f"untracked_{edge}"] += 1
                continue
            if self.max_marker_error_m is not None and body.mean_error_m > self.max_marker_error_m:
                self.ignore(f"marker_error_{edge}", f"{edge}: mean marker error over the limit")
                continue
            translation = np.array(body.position_m)
            covariance = in_place_covariance(translation, self.pose_covariance)
            measurements.append(
                (edge, ErrorPose(stamp, np.array(body.rotation), translation, covariance))
            )
        return measurements

    def _unmapped(self, body_id: int) -> None:
        """Count a body without an edge: one with no name yet while bodies are mapped by
        name (the model definitions are asked for again), else an unmapped one."""
        if body_id not in self.names and self.by_name:
            self.wants_models = True
            self.ignore("before_model_definitions", f"rigid body {body_id} has no name yet")
            return
        if body_id not in self._unmapped_ids and len(self._unmapped_ids) < MAX_UNMAPPED:
            self._unmapped_ids.add(body_id)
        known = body_id in self._unmapped_ids
        counter = f"unmapped_body_{body_id}" if known else "unmapped_body_other"
        name = self.names.get(body_id)
        self.ignore(
            counter, f"rigid body {body_id}" + (f" ({name})" if name else "") + " is not mapped"
        )

    def _device_ns(self, frame: natnet.Frame, received_ns: int) -> int | None:
        """The receive time minus NatNet's latency (transmit minus mid-exposure), ``None``
        without a usable one (counted)."""
        if self.timestamps != "device":
            return None
        frequency = self.server.clock_frequency_hz if self.server else None
        ticks = frame.transmit_ticks - frame.mid_exposure_ticks
        if frequency and frame.mid_exposure_ticks and ticks >= 0:
            latency_ns = ticks * 1_000_000_000 // frequency
            if latency_ns <= MAX_LATENCY_NS:
                return received_ns - latency_ns
        self.ignore(
            "latency_unusable",
            "no usable NatNet latency; the receive time is used",
            logging.WARNING,
        )
        return None
