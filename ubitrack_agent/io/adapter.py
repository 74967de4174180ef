"""Sensor adapters: a device's own output in, measurements of announced SRG edges out.

A sensor adapter connects one kind of device (an A.R.T. DTrack system, and next VRPN, NatNet
or an OpenCV camera) to the middleware. It is a subclass of :class:`SensorAdapter` with four
jobs, following the conventions of :mod:`ubitrack_agent.core.measurements`:

1. **Announce.** Its ``__init__`` maps the device's items (body ids, marker ids, cameras) to
   SRG edges and hands them to the base; :attr:`SensorAdapter.edges` is what a
   :class:`~ubitrack_agent.io.provider.Provider` announces.
2. **Convert on entry.** :meth:`SensorAdapter.convert` turns one unit of device output (a
   datagram, a frame) into ``(edge name, measurement)`` pairs in the middleware's units and
   conventions: metres, quaternions ``(x, y, z, w)``, pose covariance 6x6 over the left
   perturbation with rotation first (:mod:`ubitrack_agent.core.uncertainty` turns per-axis
   figures into it). Input that breaks the device's format raises :class:`RejectedInput`; a
   valid item the adapter has no edge for, or a kind of data it does not support, is passed
   to :meth:`SensorAdapter.ignore`.
3. **Timestamp** through :meth:`SensorAdapter.stamp`, by the adapter's policy:

   * ``"receive"`` (the default): the host's clock when the input arrived
     (the process's clock, ``net.clock``), which includes the transport's latency but needs no
     synchronisation with the device's clock;
   * ``"device"``: the device's own time of measurement, converted by the subclass to Unix
     nanoseconds, for a device whose clock is synchronised with the host's (NTP, PTP); an
     input without one gets the receive time.

4. **Publish and count.** :meth:`SensorAdapter.handle` converts, publishes and counts into
   :attr:`SensorAdapter.counters`: ``received`` inputs, ``rejected`` inputs (logged as
   warnings, rate-limited: :func:`~ubitrack_agent.net.logs.rate_limited`), ``published``
   measurements, and each ignored item under the subclass's name for it (logged once).
   Nothing a device sends is fatal. An adapter whose every unit of input is one whole frame of
   the device (:attr:`SensorAdapter.whole_frames`: a DTrack datagram lists every body tracked
   in it) also tells the provider which dynamic edges the frame left out: they missed their
   sample (hidden, or the tracker lost them), and an edge left out of two frames in a row has
   its token withdrawn as the second arrives (``io.flowing``), with no margin for jitter.

Running one, for a device that sends UDP datagrams::

    adapter = DTrackAdapter("ART", {0: "WT", 1: "HT"}, static_bodies=("WT",))
    with (
        open_udp_socket("0.0.0.0", 5000) as sock,
        open_session(settings) as session,
        Provider(
            session, KeySpace(settings.key_prefix), "ART", adapter.edges, settings.host_name
        ) as provider,
    ):
        serve_udp(sock, adapter, provider, stop)
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from abc import ABC, abstractmethod
from collections import Counter
from collections.abc import Collection, Iterable
from typing import ClassVar, Generic, Literal, Protocol, TypeVar, get_args

import numpy as np

from ubitrack_agent.core import Measurement
from ubitrack_agent.core.uncertainty import expected_error
from ubitrack_agent.io.provider import EdgeAnnouncement
from ubitrack_agent.net.clock import Clock
from ubitrack_agent.net.logs import count_problem

log = logging.getLogger("ubitrack.adapter")

TimestampPolicy = Literal["receive", "device"]
TIMESTAMP_POLICIES: tuple[str, ...] = get_args(TimestampPolicy)

MAX_DATAGRAM = 65_535

RawInput = TypeVar("RawInput")
"""What one unit of a device's output is: ``bytes`` for a datagram, an image for a frame."""


class RejectedInput(ValueError):
    """One unit of device output does not follow the device's format; the message says how."""


class Publisher(Protocol):
    """What an adapter needs of :class:`~ubitrack_agent.io.provider.Provider`."""

    def publish(self, edge_name: str, measurement: Measurement) -> None: ...

    def missed(self, edge_name: str) -> None: ...


class SensorAdapter(ABC, Generic[RawInput]):
    """Base of the sensor adapters (see the module docstring): subclasses name their unit of
    input (``SensorAdapter[bytes]`` for datagrams), pass their edges to ``__init__``, implement
    :meth:`convert`, and call :meth:`stamp` and :meth:`ignore`."""

    device: ClassVar[str] = "sensor"
    """The device's name in log messages."""
    whole_frames: ClassVar[bool] = False
    """Whether every valid unit of input is one whole frame listing all the device tracks in
    it: a dynamic edge the unit leaves out missed its sample (:meth:`handle`)."""

    def __init__(
        self, edges: Iterable[EdgeAnnouncement], timestamps: TimestampPolicy = "receive"
    ) -> None:
        if timestamps not in TIMESTAMP_POLICIES:
            raise ValueError(f"timestamp policy {timestamps!r} is not one of {TIMESTAMP_POLICIES}")
        self.edges = tuple(edges)
        names = [edge.name for edge in self.edges]
        if duplicates := sorted({name for name in names if names.count(name) > 1}):
            raise ValueError(f"two edges would be named {duplicates[0]!r}")
        self.timestamps = timestamps
        self.counters: Counter[str] = Counter()
        self._dynamic = frozenset(edge.name for edge in self.edges if edge.streams)

    @abstractmethod
    def convert(self, raw: RawInput, received_ns: int) -> list[tuple[str, Measurement]]:
        """The measurements in one unit of device output that arrived at ``received_ns``;
        raises :class:`RejectedInput` if it does not follow the device's format."""

    def stamp(self, device_ns: int | None, received_ns: int) -> int:
        """The timestamp the policy gives a measurement the device dates ``device_ns`` (Unix
        nanoseconds, ``None`` if the input carries no time) and the host received at
        ``received_ns``."""
        if self.timestamps == "device" and device_ns is not None:
            return device_ns
        return received_ns

    def ignore(self, counter: str, reason: str, level: int = logging.INFO) -> None:
        """Count under ``counter`` valid input the adapter leaves out (an item that has no
        edge, a data type it does not support); log ``reason`` at ``level`` the first time
        only, never per input."""
        if not self.counters[counter]:
            log.log(level, "%s: %s; ignored", self.device, reason)
        self.counters[counter] += 1

    def handle(self, raw: RawInput, received_ns: int, publisher: Publisher) -> int:
        """Convert one unit of device output and publish its measurements; returns how many
        were published (0 for rejected input, which is logged and counted). With
        :attr:`whole_frames`, each dynamic edge the unit left out is reported missed after
        them: O(edges) a unit."""
        self.counters["received"] += 1
        try:
            measurements = self.convert(raw, received_ns)
        except RejectedInput as exc:
            count_problem(
                self.counters,
                "rejected",
                log,
                "%s: rejected input (%d so far): %s",
                self.device,
                self.counters["rejected"] + 1,
                exc,
            )
            return 0
        for edge_name, measurement in measurements:
            publisher.publish(edge_name, measurement)
            self.counters["published"] += 1
        if self.whole_frames:
            for edge_name in self._dynamic.difference(name for name, _ in measurements):
                publisher.missed(edge_name)
        return len(measurements)


def pose_edges(
    tracker: str,
    frames: Iterable[str],
    static_frames: Collection[str],
    rate: float | None,
    covariance: np.ndarray,
) -> list[EdgeAnnouncement]:
    """The 6D edges ``tracker -> frame`` of a tracker's bodies, static for those in
    ``static_frames`` (measured again at the tracker's rate all the same, so each sample has
    an error of its own: ``net.spec.InputBinding.fixed_error``), announcing as ``sigma`` the
    expected error of ``covariance``
    (:func:`~ubitrack_agent.core.uncertainty.expected_error`)."""
    sigma = expected_error(covariance)
    return [
        EdgeAnnouncement(
            tracker,
            frame,
            "6D",
            static=frame in static_frames,
            rate=rate,
            sigma=sigma,
        )
        for frame in frames
    ]


def open_udp_socket(host: str, port: int) -> socket.socket:
    """A UDP socket bound to ``host:port`` with a short timeout, so :func:`serve_udp` notices
    ``stop``; ``OSError`` if the address cannot be bound."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind((host, port))
    except OSError:
        sock.close()
        raise
    sock.settimeout(0.1)
    return sock


def serve_udp(
    sock: socket.socket,
    adapter: SensorAdapter[bytes],
    publisher: Publisher,
    stop: threading.Event,
    duration_s: float | None = None,
    clock: Clock | None = None,
) -> None:
    """Hand each datagram arriving on ``sock`` to ``adapter`` (stamped with the receive time on
    ``clock``, the process's: ``net.clock``) until ``stop`` is set or ``duration_s`` seconds
    have passed."""
    clock = clock or Clock()
    end = None if duration_s is None else time.monotonic() + duration_s
    while not stop.is_set() and (end is None or time.monotonic() < end):
        try:
            datagram = sock.recv(MAX_DATAGRAM)
        except TimeoutError:
            continue
        adapter.handle(datagram, clock.now_ns(), publisher)
