"""Small helpers for integration tests that talk zenoh on loopback."""

from __future__ import annotations

import queue
import socket
import time
from collections.abc import Callable
from typing import Any

from ubitrack_agent.net import config
from ubitrack_agent.net.session import open_session


def free_port() -> int:
    """A TCP port on loopback that was free a moment ago."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def hub_session(port: int):
    """A hub (peer listening on ``port``) for a test; the caller closes it."""
    return open_session(config.Settings(listen=(f"tcp/127.0.0.1:{port}",)))


def member_flags(port: int, domain: str) -> list[str]:
    """Command-line flags making a child process join the test's hub."""
    return config.member_flags(config.Settings(listen=(f"tcp/127.0.0.1:{port}",), domain=domain))


def wait_until(condition: Callable[[], Any], timeout: float = 10.0, interval: float = 0.01) -> Any:
    """Poll ``condition`` until it returns something truthy; fail after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        result = condition()
        if result:
            return result
        time.sleep(interval)
    raise AssertionError(f"condition not met within {timeout} s")


class Collector:
    """Subscribes to a key and queues payloads (the callback only queues)."""

    def __init__(self, session, key: str) -> None:
        self.items: queue.SimpleQueue[bytes] = queue.SimpleQueue()
        self.subscriber = session.declare_subscriber(
            key, lambda s: self.items.put(s.payload.to_bytes())
        )

    def next(self, timeout: float = 5.0) -> bytes:
        return self.items.get(timeout=timeout)

    def drain(self) -> None:
        while not self.items.empty():
            self.items.get_nowait()
