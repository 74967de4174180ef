"""Simulated OptiTrack Motive: a NatNet server streaming the scenario's tracked bodies.

An OptiTrack in place of the A.R.T.: it reads the scenario's ``art`` section (tracker frame,
bodies, noise, dropout, rate) and measures the same world, so ``ubitrack demo --tracker
natnet`` runs the paper's setup on NatNet. Motive names each rigid body: here its frame's
name, with streaming id = the DTrack body id + 1 (Motive counts from 1). Single markers
(``art.markers``) are not streamed.

* **Command channel** (:meth:`NatNetServer.serve_commands`): ``NAT_CONNECT`` is answered with
  ``NAT_SERVERINFO`` (application "Motive", the configured NatNet version, clock frequency
  1 GHz, data port, transmission type; a different version asked for in the connect is not
  granted, counted ``version_not_granted``); ``NAT_REQUEST_MODELDEF`` with ``NAT_MODELDEF``;
  ``NAT_KEEPALIVE`` keeps a unicast client; other requests get ``NAT_UNRECOGNIZED_REQUEST``.
  A malformed packet is counted (``rejected``) and logged rate-limited, never answered.
* **Data channel**: every frame is sent to the multicast group's data port
  (``multicast_group``, with ``multicast_ttl``: 0 keeps it on this host), or unicast from the
  data port (the source libNatNet expects) to each client whose connect or keep-alive arrived
  in the last :data:`CLIENT_TIMEOUT_S` seconds.
* **Frames** (:meth:`NatNetSimulator.frame`): each body's pose in the tracker frame at the
  exposure time with in-place noise
  (:func:`ubitrack_agent.sim_trackers.noise.perturb_in_place`), untracked
  (tracking-valid flag clear, pose zero) with probability ``art.dropout``, a mean marker
  error drawn as the length of a position-noise vector; the mid-exposure and transmit stamps
  on the host's monotonic clock in nanoseconds, ``latency_ms`` apart, so an adapter stamping
  "device" times (receive minus that latency) recovers the exposure time.

A frame costs O(bodies) to make and O(clients) sends; a command O(bodies) (the model
definitions) or O(1).
"""

from __future__ import annotations

import dataclasses
import logging
import socket
import threading
import time
from collections import Counter

import numpy as np
from scipy.spatial.transform import Rotation

from ubitrack_agent.core.uncertainty import isotropic_pose_covariance
from ubitrack_agent.io.adapter import MAX_DATAGRAM
from ubitrack_agent.io.natnet import format as natnet
from ubitrack_agent.io.natnet.format import NatNetFormatError, NatNetVersion
from ubitrack_agent.net.logs import count_problem
from ubitrack_agent.sim_trackers.noise import perturb_in_place
from ubitrack_agent.sim_trackers.scenario import ArtSettings
from ubitrack_agent.sim_trackers.world import World

log = logging.getLogger("ubitrack.sim.natnet")

DEFAULT_VERSION = NatNetVersion(4, 1)
"""The NatNet version Motive 3.1 streams."""

CLOCK_FREQUENCY_HZ = 1_000_000_000
"""The simulated high-resolution clock: the host's monotonic clock in nanoseconds."""

CLIENT_TIMEOUT_S = 5.0
"""A unicast client is dropped after this long without a connect or keep-alive."""


def body_names(art: ArtSettings) -> dict[str, str]:
    """``--body NAME=FRAME`` pairs that read this simulator: each body's name is its frame."""
    return {frame: frame for frame in art.bodies.values()}


class NatNetSimulator:
    """Makes the NatNet frames an OptiTrack would see in ``world`` (see the module docstring)."""

    def __init__(
        self,
        world: World,
        settings: ArtSettings,
        rng: np.random.Generator,
        latency_ms: float = 2.0,
    ) -> None:
        self.world = world
        self.settings = settings
        self.rng = rng
        self.latency_ns = round(latency_ms * 1e6)
        self.covariance = isotropic_pose_covariance(
            np.radians(settings.noise.rotation_deg), settings.noise.position_mm / 1000.0
        )
        self.frame_number = 0

    def descriptions(self) -> list[natnet.RigidBodyDescription]:
        """The rigid bodies Motive would define: name = frame, id = DTrack id + 1, four
        markers 5 cm around the origin."""
        markers = ((0.05, 0.0, 0.0), (0.0, 0.05, 0.0), (-0.05, 0.0, 0.0), (0.0, 0.0, 0.05))
        return [
            natnet.RigidBodyDescription(frame, body_id + 1, -1, (0.0, 0.0, 0.0), markers)
            for body_id, frame in sorted(self.settings.bodies.items())
        ]

    def frame(self, exposure_ns: int, exposure_ticks: int) -> natnet.Frame:
        """The frame exposed at the real time ``exposure_ns`` (monotonic clock reading
        ``exposure_ticks``), its transmit stamp ``latency_ms`` later; the server restamps the
        transmit time when it sends later than that (:meth:`NatNetServer.send_frame`)."""
        sigma_m = self.settings.noise.position_mm / 1000.0
        bodies = []
        for body_id, name in sorted(self.settings.bodies.items()):
            if self.rng.random() < self.settings.dropout:
                bodies.append(
                    natnet.RigidBody(body_id + 1, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0), 0.0, False)
                )
                continue
            q, t = perturb_in_place(
                self.rng,
                *self.world.pose(self.settings.frame, name, exposure_ns),
                self.covariance,
            )
            error = float(np.linalg.norm(self.rng.normal(0.0, sigma_m, 3)))
            quaternion = Rotation.from_quat(q).as_quat(canonical=False)
            bodies.append(
                natnet.RigidBody(
                    body_id + 1, tuple(map(float, t)), tuple(map(float, quaternion)), error
                )
            )
        self.frame_number += 1
        return natnet.Frame(
            self.frame_number,
            tuple(bodies),
            timestamp_s=exposure_ticks / 1e9,
            mid_exposure_ticks=exposure_ticks,
            data_received_ticks=exposure_ticks + self.latency_ns // 2,
            transmit_ticks=exposure_ticks + self.latency_ns,
        )


class NatNetServer:
    """The simulator's two sockets (see the module docstring); a context manager.
    ``OSError`` if a port cannot be bound."""

    def __init__(
        self,
        simulator: NatNetSimulator,
        host: str = "127.0.0.1",
        command_port: int = 1510,
        data_port: int = 1511,
        version: NatNetVersion = DEFAULT_VERSION,
        multicast_group: str | None = None,
        multicast_ttl: int = 0,
    ) -> None:
        if not natnet.supported(version):
            raise ValueError(f"NatNet {version} is not supported (3.0 to 4.x are)")
        self.simulator = simulator
        self.version = version
        self.multicast_group = multicast_group
        self.counters: Counter[str] = Counter()
        self.clients: dict[tuple[str, int], float] = {}
        """Unicast clients and when they were last heard of (monotonic seconds)."""
        self.command = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.data = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.command.bind((host, command_port))
            # Unicast frames leave from the data port (libNatNet checks it); multicast ones
            # from any port, so a client on this host can bind the data port to receive.
            self.data.bind((host, data_port if multicast_group is None else 0))
            if multicast_group is not None:
                self.data.setsockopt(
                    socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(host)
                )
                self.data.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, multicast_ttl)
        except OSError:
            self.close()
            raise
        self.command.settimeout(0.1)
        self.data_port = data_port if multicast_group else self.data.getsockname()[1]
        self.info = natnet.ServerInfo(
            "Motive",
            NatNetVersion(3, 1),
            version,
            CLOCK_FREQUENCY_HZ,
            self.data_port,
            multicast_group is not None,
            multicast_group or "0.0.0.0",
        )

    def __enter__(self) -> NatNetServer:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

    def close(self) -> None:
        self.command.close()
        self.data.close()

    def answer(self, datagram: bytes, sender: tuple[str, int]) -> bytes | None:
        """The reply to one command-channel datagram, ``None`` for none (a keep-alive, a
        malformed packet: counted ``rejected``). Any connect payload is accepted (libNatNet's
        269 bytes, the SDK's Python sample's 270, older clients' ``Ping``), and so is a
        request whose header size disagrees with its payload, as older clients send."""
        if len(datagram) < 4:
            count_problem(
                self.counters,
                "rejected",
                log,
                "sim natnet: %d-byte packet from %s",
                len(datagram),
                sender,
            )
            return None
        message_id = int.from_bytes(datagram[:2], "little")
        self.counters[f"message_{message_id}" if message_id < 256 else "message_other"] += 1
        if message_id == natnet.NAT_CONNECT:
            requested = natnet.parse_connect(datagram[4:])
            if requested is not None and requested[:2] != self.version[:2]:
                self.counters["version_not_granted"] += 1
            self.clients[sender] = time.monotonic()
            return natnet.build_server_info(self.info)
        if message_id == natnet.NAT_KEEPALIVE:
            if sender in self.clients:
                self.clients[sender] = time.monotonic()
            return None
        if message_id == natnet.NAT_REQUEST_MODELDEF:
            return natnet.build_model_definitions(self.simulator.descriptions(), self.version)
        return natnet.packet(natnet.NAT_UNRECOGNIZED_REQUEST)

    def serve_commands(self, stop: threading.Event) -> None:
        """Answer the command channel until ``stop`` is set."""
        while not stop.is_set():
            try:
                datagram, sender = self.command.recvfrom(MAX_DATAGRAM)
            except TimeoutError:
                continue
            except OSError as exc:  # closed, or ICMP unreachable reported by Linux
                if stop.is_set():
                    return
                log.debug("sim natnet: command receive failed: %s", exc)
                continue
            try:
                reply = self.answer(datagram, sender)
            except NatNetFormatError as exc:  # cannot happen for these messages; kept total
                count_problem(self.counters, "rejected", log, "sim natnet: %s", exc)
                continue
            if reply is not None:
                self._send(self.command, reply, sender)

    def _send(self, sock: socket.socket, message: bytes, address: tuple[str, int]) -> None:
        try:
            sock.sendto(message, address)
            self.counters["sent"] += 1
        except OSError as exc:  # e.g. ICMP port unreachable reported on a later send
            self.counters["send_failed"] += 1
            log.debug("sim natnet: send to %s:%d failed: %s", *address, exc)

    def send_frame(self, now_ns: int) -> None:
        """Send the frame exposed ``latency_ms`` before the real time ``now_ns`` to the group
        or the live unicast clients, its transmit stamp the moment it is built (so the
        latency it reports includes the time spent making it, as Motive's does)."""
        ticks_now = time.monotonic_ns() - (time.time_ns() - now_ns)
        latency = self.simulator.latency_ns
        frame = self.simulator.frame(now_ns - latency, ticks_now - latency)
        transmit = max(frame.transmit_ticks, time.monotonic_ns())
        message = natnet.build_frame(
            dataclasses.replace(frame, transmit_ticks=transmit), self.version
        )
        self.counters["frames"] += 1
        if self.multicast_group is not None:
            self._send(self.data, message, (self.multicast_group, self.data_port))
            return
        horizon = time.monotonic() - CLIENT_TIMEOUT_S
        for client, seen in list(self.clients.items()):
            if seen < horizon:
                del self.clients[client]
            else:
                self._send(self.data, message, client)
