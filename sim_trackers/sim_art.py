"""Simulated A.R.T. tracker: DTrack2 ASCII datagrams over UDP from the scenario's ground truth.

Each frame it measures the poses of the scenario's ``art.bodies`` in the tracker frame, adds
noise (rotation about each body's origin and position noise, as an outside-in tracker's errors
behave: :func:`ubitrack_agent.sim_trackers.noise.perturb_in_place`), drops each body with
probability ``art.dropout`` (an untracked body is omitted from the ``6d`` line, as DTrack does,
while ``6dcal`` still counts it) and sends ``fr``/``ts``/``6dcal``/``6d``/``3d`` lines
(:mod:`ubitrack_agent.io.dtrack.format`). ``ts`` is the sample time in seconds since 00:00 UTC
with microseconds, so sample times are whole microseconds: the DTrack adapter maps ``ts`` back
to exactly the nanosecond timestamp the ground truth was evaluated at, on the controller's
clock (:class:`~ubitrack_agent.net.clock.Clock`, ``--clock-offset-ms``: a controller, and the
host its adapter runs on, whose clock is off; the world moves on real time).
"""

from __future__ import annotations

import logging
import socket
import threading
from collections import Counter

import numpy as np
from scipy.spatial.transform import Rotation

from ubitrack_agent.core.uncertainty import isotropic_pose_covariance
from ubitrack_agent.io.adapter import TimestampPolicy
from ubitrack_agent.io.dtrack.adapter import DTrackAdapter
from ubitrack_agent.io.dtrack.format import (
    Body6D,
    DTrackFrame,
    Marker3D,
    encode_frame,
    seconds_of_day,
)
from ubitrack_agent.net.clock import Clock
from ubitrack_agent.sim_trackers.noise import perturb_in_place
from ubitrack_agent.sim_trackers.runtime import run_periodic
from ubitrack_agent.sim_trackers.scenario import ArtSettings
from ubitrack_agent.sim_trackers.world import World

log = logging.getLogger("ubitrack.sim.art")


def dtrack_adapter(art: ArtSettings, timestamps: TimestampPolicy = "receive") -> DTrackAdapter:
    """The DTrack adapter that reads this simulator (the scenario's ``art`` section): its
    tracker frame, body and marker mapping, static bodies, noise and rate, as
    ``ubitrack_agent.commands.demo.dtrack_flags`` gives them to ``ubitrack dtrack``."""
    return DTrackAdapter(
        art.frame,
        art.bodies,
        art.static_bodies,
        art.markers,
        sigma_mm=art.noise.position_mm,
        sigma_deg=art.noise.rotation_deg,
        rate=art.rate,
        timestamps=timestamps,
    )


class ArtSimulator:
    """Makes the DTrack frames an A.R.T. system would see in ``world``."""

    def __init__(
        self,
        world: World,
        settings: ArtSettings,
        rng: np.random.Generator,
        clock: Clock | None = None,
    ) -> None:
        self.world = world
        self.settings = settings
        self.rng = rng
        offset_ns = 0 if clock is None else clock.offset_ns
        self.clock = Clock(offset_ns - offset_ns % 1000)
        """The controller's clock, which stamps the frames (whole microseconds, as ``ts``)."""
        self.covariance = isotropic_pose_covariance(
            np.radians(settings.noise.rotation_deg), settings.noise.position_mm / 1000.0
        )
        self.frame_counter = 0

    def _tracked(self) -> bool:
        return self.rng.random() >= self.settings.dropout

    def frame(self, timestamp_ns: int) -> DTrackFrame:
        """The frame at the real time ``timestamp_ns``, a whole number of microseconds
        (stamped on :attr:`clock`)."""
        if timestamp_ns % 1000:
            raise ValueError("DTrack timestamps carry microseconds: round timestamp_ns to them")
        tracker = self.settings.frame
        bodies = []
        for body_id, name in sorted(self.settings.bodies.items()):
            if not self._tracked():
                continue
            q, t = perturb_in_place(
                self.rng, *self.world.pose(tracker, name, timestamp_ns), self.covariance
            )
            bodies.append(Body6D(body_id, 1.0, t * 1000.0, Rotation.from_quat(q).as_matrix()))
        sigma_mm = self.settings.noise.position_mm
        markers = [
            Marker3D(
                marker_id,
                1.0,
                self.world.pose(tracker, name, timestamp_ns)[1] * 1000.0
                + self.rng.normal(0.0, sigma_mm, 3),
            )
            for marker_id, name in sorted(self.settings.markers.items())
            if self._tracked()
        ]
        self.frame_counter += 1
        return DTrackFrame(
            frame=self.frame_counter,
            timestamp_s=seconds_of_day(self.clock.reading(timestamp_ns)),
            calibrated_bodies=len(self.settings.bodies),
            bodies=tuple(bodies),
            markers=tuple(markers),
        )


def run(
    simulator: ArtSimulator,
    address: tuple[str, int],
    rate_hz: float,
    stop: threading.Event,
    duration_s: float | None = None,
    counters: Counter[str] | None = None,
) -> int:
    """Send one datagram per frame to ``address`` until stopped, counting ``sent`` and
    ``send_failed`` in ``counters``; returns the frames sent."""
    counted = Counter() if counters is None else counters
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:

        def send(now_ns: int) -> None:
            datagram = encode_frame(simulator.frame(now_ns - now_ns % 1000))
            try:
                sock.sendto(datagram, address)
                counted["sent"] += 1
            except OSError as exc:  # e.g. ICMP port unreachable reported on a later send
                counted["send_failed"] += 1
                log.debug("send to %s:%d failed: %s", *address, exc)

        frames = run_periodic(rate_hz, send, stop, duration_s)
    log.info("sent %d DTrack frames to %s:%d", frames, *address)
    return frames
