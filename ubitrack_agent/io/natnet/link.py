"""The client side of NatNet's two UDP channels, feeding a :class:`~.adapter.NatNetAdapter`.

NatNet (OptiTrack's SDK documentation; the SDK samples' ``NatNetClient.py``; libNatNet 4.x's
observed behaviour) has a *command* channel, the server's port 1510, and a *data* channel,
its port 1511:

* **Command.** The client sends ``NAT_CONNECT`` from one socket; the server replies
  ``NAT_SERVERINFO`` (its versions, clock frequency, data port) to that socket's address, and
  ``NAT_MODELDEF`` to ``NAT_REQUEST_MODELDEF``. Until the server info arrives the link resends
  the connect every :data:`CONNECT_RETRY_S` (or ``interval_s`` if shorter); it asks for the
  model definitions whenever the adapter wants them
  (:attr:`~.adapter.NatNetAdapter.wants_models`), at most once per ``interval_s``.
* **Data, multicast** (Motive's default): frames go to a group (239.255.42.99) on the data
  port; the link joins the group on ``interface`` with a second socket bound to that port.
* **Data, unicast**: the server sends frames, from its data port, to the address the connect
  came from, i.e. the command socket; the client sends ``NAT_KEEPALIVE`` once per
  ``interval_s`` so the server keeps streaming.

Datagrams from any host but the server are dropped and counted (``foreign_sender``). Each
loop iteration is O(1) besides the packets it hands over.
"""

from __future__ import annotations

import logging
import select
import socket
import threading
import time

from ubitrack_agent.io.adapter import MAX_DATAGRAM, Publisher
from ubitrack_agent.io.natnet import format as natnet
from ubitrack_agent.io.natnet.adapter import NatNetAdapter
from ubitrack_agent.net.clock import Clock

log = logging.getLogger("ubitrack.natnet")

CLIENT_NAME = "ubitrack"

CONNECT_RETRY_S = 0.25
"""How often the connect is resent until the server answers: soon enough that an adapter
started beside its server publishes well within the agent's data-liveness second."""


class NatNetLink:
    """The sockets of one connection to a NatNet server (see the module docstring); use it
    as a context manager. ``OSError`` if a socket cannot be opened."""

    def __init__(
        self,
        server: str,
        command_port: int = 1510,
        data_port: int = 1511,
        multicast_group: str | None = "239.255.42.99",
        interface: str = "0.0.0.0",
        requested: natnet.NatNetVersion | None = None,
        interval_s: float = 1.0,
    ) -> None:
        self.server_address = (socket.gethostbyname(server), command_port)
        self.data_port = data_port
        self.multicast_group = multicast_group
        self.interface = interface
        self.requested = requested
        self.interval_s = interval_s
        self.command = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.data: socket.socket | None = None
        try:
            self.command.bind((interface, 0))
            if multicast_group is not None:
                self.data = _multicast_socket(multicast_group, data_port, interface)
        except OSError:
            self.close()
            raise
        self._last_connect = self._last_models = self._last_keepalive = -float("inf")

    def __enter__(self) -> NatNetLink:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

    def close(self) -> None:
        self.command.close()
        if self.data is not None:
            self.data.close()

    def _send(self, message: bytes) -> None:
        try:
            self.command.sendto(message, self.server_address)
        except OSError as exc:  # e.g. no route; the next interval tries again
            log.debug("NatNet: sending to %s:%d failed: %s", *self.server_address, exc)

    def housekeeping(self, adapter: NatNetAdapter, now: float) -> None:
        """Connect until the server answers, keep a unicast stream alive, and ask for the
        model definitions when the adapter wants them, each at most once per interval."""
        if adapter.server is None:
            if now - self._last_connect >= min(self.interval_s, CONNECT_RETRY_S):
                self._send(natnet.build_connect(CLIENT_NAME, self.requested))
                self._last_connect = now
            return
        if self.multicast_group is None and now - self._last_keepalive >= self.interval_s:
            self._send(natnet.build_request(natnet.NAT_KEEPALIVE))
            self._last_keepalive = now
        if adapter.wants_models and now - self._last_models >= self.interval_s:
            self._send(natnet.build_request(natnet.NAT_REQUEST_MODELDEF))
            self._last_models = now

    def serve(
        self,
        adapter: NatNetAdapter,
        publisher: Publisher,
        stop: threading.Event,
        duration_s: float | None = None,
        clock: Clock | None = None,
    ) -> None:
        """Hand every datagram from the server to ``adapter`` (stamped on ``clock``, the
        process's) until ``stop`` is set or ``duration_s`` seconds have passed."""
        clock = clock or Clock()
        sockets = [s for s in (self.command, self.data) if s is not None]
        end = None if duration_s is None else time.monotonic() + duration_s
        while not stop.is_set() and (end is None or time.monotonic() < end):
            self.housekeeping(adapter, time.monotonic())
            readable, _, _ = select.select(sockets, [], [], 0.05)
            for sock in readable:
                try:
                    datagram, (host, _) = sock.recvfrom(MAX_DATAGRAM)
                except OSError as exc:  # e.g. ICMP port unreachable reported by Linux
                    log.debug("NatNet: receive failed: %s", exc)
                    continue
                if host != self.server_address[0]:
                    adapter.ignore("foreign_sender", f"datagrams from {host}, not the server")
                    continue
                adapter.handle(datagram, clock.now_ns(), publisher)


def _multicast_socket(group: str, port: int, interface: str) -> socket.socket:
    """A socket bound to ``port`` that has joined ``group`` on ``interface``."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(("", port))
        membership = socket.inet_aton(group) + socket.inet_aton(interface)
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, membership)
    except OSError:
        sock.close()
        raise
    return sock
