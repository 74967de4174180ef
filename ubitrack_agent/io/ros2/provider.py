"""A robot's tf tree as SRG edges: /tf and /tf_static (rmw_zenoh) in, a provider out.

:class:`TfAdapter` is a :class:`~ubitrack_agent.io.adapter.SensorAdapter` whose unit of input
is one received sample (:class:`~.subscriber.TfSample`):

* **Checks.** The attachment must be rmw_zenoh's (:mod:`.attachment`; a ROS 2 subscriber
  drops a sample without one) and the payload a TFMessage in CDR (:mod:`.cdr`); otherwise
  the sample is rejected (``rejected``, and ``rejected_attachment`` or ``rejected_payload``).
  A transform whose frame id has no SRG name (:mod:`.frames`) is left out and counted
  (``refused_frame``), as is one from a frame to itself (``self_transform``).
* **Edges.** Each ``parent -> child`` transform is the 6D edge ``<parent> -> <child>``
  (tf's ``frame_id`` is the source: the pose of the child in the parent, as in the SRG), static
  when it came on /tf_static. The first sample of a pair announces it; a pair that later
  arrives on the other topic is left out (``static_and_dynamic``), and so is one whose edge
  name ``<parent>_<child>`` another pair already has (``edge_name_clash``).
* **Values.** An :class:`~ubitrack_agent.core.ErrorPose` with the configured noise as
  covariance (tf carries none; ``sigma_mm`` / ``sigma_deg`` per axis), stamped by the
  adapter's policy: ``"device"`` (the default) is the header stamp, which ROS takes from the
  measurement; a zero stamp gets the receive time.

:class:`GrowingProvider` announces the edges as they appear: the provider of
:mod:`ubitrack_agent.io.provider` announces a fixed set, so a sample of a new edge closes it
and declares it again with every edge so far (the agent replans once per new set; a robot's
tree arrives in its first messages), and publishes the latest value of each static edge again,
so late workers still get it. O(transforms) per sample; a re-announcement is O(edges).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from ubitrack_agent.core import ErrorPose, Measurement, MeasurementError
from ubitrack_agent.core.uncertainty import expected_error, isotropic_pose_covariance
from ubitrack_agent.io.adapter import Publisher, RejectedInput, SensorAdapter, TimestampPolicy
from ubitrack_agent.io.provider import EdgeAnnouncement, Provider
from ubitrack_agent.io.ros2.attachment import AttachmentError, decode_attachment
from ubitrack_agent.io.ros2.cdr import TfDecodeError, decode_tf
from ubitrack_agent.io.ros2.frames import FrameNameError, FrameNames
from ubitrack_agent.io.ros2.subscriber import TfSample, TfSubscriber
from ubitrack_agent.net import logs
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.lifecycle import Closing

log = logging.getLogger("ubitrack.ros2")

DEFAULT_SIGMA_MM = 1.0
"""Assumed position noise per axis of a tf transform (mm): tf has no covariance."""
DEFAULT_SIGMA_DEG = 0.1
"""Assumed rotation noise per axis of a tf transform (degrees)."""


class TfAdapter(SensorAdapter[TfSample]):
    """The adapter of the module docstring; :attr:`edges` grows as pairs appear."""

    device = "ros2"

    def __init__(
        self,
        frames: FrameNames | None = None,
        sigma_mm: float = DEFAULT_SIGMA_MM,
        sigma_deg: float = DEFAULT_SIGMA_DEG,
        rate: float | None = None,
        timestamps: TimestampPolicy = "device",
    ) -> None:
        super().__init__((), timestamps)
        if not (sigma_mm > 0 and sigma_deg > 0):
            raise ValueError("sigma_mm and sigma_deg must be positive")
        self.frames = frames or FrameNames()
        self.covariance = isotropic_pose_covariance(math.radians(sigma_deg), sigma_mm / 1000)
        self._sigma = expected_error(self.covariance)
        self._rate = rate
        self._pairs: dict[str, tuple[str, str, bool]] = {}

    def convert(self, raw: TfSample, received_ns: int) -> list[tuple[str, Measurement]]:
        try:
            decode_attachment(raw.attachment)
        except AttachmentError as exc:
            self.counters["rejected_attachment"] += 1
            raise RejectedInput(f"attachment: {exc}") from None
        try:
            transforms = decode_tf(raw.payload)
        except TfDecodeError as exc:
            self.counters["rejected_payload"] += 1
            raise RejectedInput(f"payload: {exc}") from None
        out: list[tuple[str, Measurement]] = []
        for transform in transforms:
            try:
                parent = self.frames.to_srg(transform.parent)
                child = self.frames.to_srg(transform.child)
            except FrameNameError as exc:
                self.ignore("refused_frame", str(exc), logging.WARNING)
                continue
            if parent == child:
                self.ignore("self_transform", f"a transform from {parent!r} to itself")
                continue
            name = self._edge(parent, child, raw.static)
            if name is None:
                continue
            stamp = self.stamp(transform.stamp_ns or None, received_ns)
            try:
                pose = ErrorPose(
                    stamp,
                    np.array(transform.rotation),
                    np.array(transform.translation),
                    self.covariance,
                )
            except MeasurementError as exc:  # a stamp before 1970, say
                self.ignore("invalid_transform", str(exc), logging.WARNING)
                continue
            out.append((name, pose))
        return out

    def _edge(self, parent: str, child: str, static: bool) -> str | None:
        """The edge's name, announcing it if new; ``None`` (counted) if it cannot be one."""
        name = f"{parent}_{child}"
        known = self._pairs.get(name)
        if known is None:
            self._pairs[name] = (parent, child, static)
            edge = EdgeAnnouncement(
                parent,
                child,
                "6D",
                static=static,
                sigma=self._sigma,
                rate=None if static else self._rate,
            )
            self.edges = (*self.edges, edge)
            return name
        if known[:2] != (parent, child):
            self.ignore("edge_name_clash", f"{parent}->{child} would be named like {known}")
            return None
        if known[2] != static:
            self.ignore(
                "static_and_dynamic",
                f"{parent}->{child} arrives on both /tf and /tf_static; kept as first seen",
                logging.WARNING,
            )
            return None
        return name


class GrowingProvider(Closing):
    """A :class:`~ubitrack_agent.io.provider.Provider` declared again with every edge of
    ``edges()`` when an edge it has not announced is published (module docstring)."""

    def __init__(
        self,
        session: Any,
        keys: KeySpace,
        provider_id: str,
        edges: Callable[[], tuple[EdgeAnnouncement, ...]],
        host: str | None = None,
    ) -> None:
        self._open = lambda: Provider(session, keys, provider_id, edges(), host)
        self._provider: Provider | None = None
        self._static_values: dict[str, Measurement] = {}
        self.announcements = 0
        self._lock = threading.Lock()

    @property
    def announced(self) -> tuple[str, ...]:
        """The names of the edges announced now."""
        return tuple(self._provider.edges) if self._provider else ()

    def publish(self, edge_name: str, measurement: Measurement) -> None:
        with self._lock:
            if self._provider is None or edge_name not in self._provider.edges:
                if self._provider is not None:
                    self._provider.close()
                self._provider = self._open()
                self.announcements += 1
                for name, value in self._static_values.items():
                    self._provider.publish(name, value)
            if self._provider.edges[edge_name].static:
                self._static_values[edge_name] = measurement
            self._provider.publish(edge_name, measurement)

    def close(self) -> None:
        with self._lock:
            if self._provider is not None:
                self._provider.close()
                self._provider = None


def serve_tf(
    subscriber: TfSubscriber,
    adapter: TfAdapter,
    publisher: Publisher,
    stop: threading.Event,
    duration_s: float | None = None,
) -> None:
    """Hand each sample ``subscriber`` receives to ``adapter`` until ``stop`` is set or
    ``duration_s`` seconds have passed."""
    handle = logs.guarded(adapter.handle, adapter.counters, log, "ros2 input")
    end = None if duration_s is None else time.monotonic() + duration_s
    while not stop.is_set() and (end is None or time.monotonic() < end):
        sample = subscriber.get(timeout=0.1)
        if sample is not None:
            handle(sample, sample.received_ns, publisher)
