"""The sensor adapter base: timestamp policy, counting, rejection, and the UDP loop, with a
toy device that sends ``<id> <x_mm> [<unix seconds>]`` lines."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest

from ubitrack_agent.core import Measurement, Position3D
from ubitrack_agent.io.adapter import (
    RejectedInput,
    SensorAdapter,
    open_udp_socket,
    serve_udp,
)
from ubitrack_agent.io.provider import EdgeAnnouncement

T0 = 1_763_700_000_000_000_000


class ToyAdapter(SensorAdapter[bytes]):
    device = "toy"

    def __init__(self, timestamps="receive") -> None:
        super().__init__([EdgeAnnouncement("T", "P1", "3D")], timestamps)

    def convert(self, raw: bytes, received_ns: int) -> list[tuple[str, Measurement]]:
        fields = raw.split()
        if len(fields) not in (2, 3) or not fields[0].isdigit():
            raise RejectedInput(f"expected '<id> <x_mm> [<time>]', got {raw!r}")
        if fields[0] != b"1":
            self.ignore(f"unmapped_{int(fields[0])}", f"id {int(fields[0])} is not mapped")
            return []
        device_ns = int(float(fields[2]) * 1e9) if len(fields) == 3 else None
        stamp = self.stamp(device_ns, received_ns)
        return [("T_P1", Position3D(stamp, [float(fields[1]) / 1000.0, 0.0, 0.0]))]


class Recorder:
    def __init__(self) -> None:
        self.published: list[tuple[str, Measurement]] = []

    def publish(self, edge_name: str, measurement: Measurement) -> None:
        self.published.append((edge_name, measurement))


def test_handle_converts_publishes_and_counts():
    adapter, recorder = ToyAdapter(), Recorder()
    assert adapter.handle(b"1 250", T0, recorder) == 1
    assert adapter.handle(b"nonsense", T0, recorder) == 0
    assert adapter.handle(b"2 10", T0, recorder) == 0
    assert adapter.counters == {"received": 3, "published": 1, "rejected": 1, "unmapped_2": 1}
    ((edge, sample),) = recorder.published
    assert edge == "T_P1" and sample.timestamp_ns == T0
    np.testing.assert_allclose(sample.position, [0.25, 0.0, 0.0])  # converted on entry


def test_timestamp_policies():
    device_time = T0 / 1e9 - 0.5
    received, device = Recorder(), Recorder()
    ToyAdapter("receive").handle(f"1 0 {device_time}".encode(), T0, received)
    ToyAdapter("device").handle(f"1 0 {device_time}".encode(), T0, device)
    ToyAdapter("device").handle(b"1 0", T0, device)  # no device time: the receive time
    assert received.published[0][1].timestamp_ns == T0
    assert [s.timestamp_ns for _, s in device.published] == [
        pytest.approx(T0 - 500_000_000, abs=1_000),
        T0,
    ]


def test_the_base_is_abstract_and_checks_its_edges():
    with pytest.raises(TypeError):
        SensorAdapter([EdgeAnnouncement("T", "P1", "3D")])  # type: ignore[abstract]

    class Twice(ToyAdapter):
        def __init__(self) -> None:
            SensorAdapter.__init__(self, [EdgeAnnouncement("T", "P1", "3D")] * 2)

    with pytest.raises(ValueError, match="two edges would be named 'T_P1'"):
        Twice()
    with pytest.raises(ValueError, match="timestamp policy"):
        ToyAdapter("ts")


def test_serve_udp_hands_datagrams_to_the_adapter_until_stopped():
    adapter, recorder, stop = ToyAdapter(), Recorder(), threading.Event()
    with open_udp_socket("127.0.0.1", 0) as sock:
        loop = threading.Thread(target=serve_udp, args=(sock, adapter, recorder, stop))
        loop.start()
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
            for datagram in (b"1 1", b"bad", b"1 2"):
                sender.sendto(datagram, sock.getsockname())
        try:
            deadline = time.monotonic() + 5.0
            while adapter.counters["received"] < 3 and time.monotonic() < deadline:
                time.sleep(0.01)
        finally:
            stop.set()
            loop.join(timeout=5)
    assert not loop.is_alive()
    assert adapter.counters == {"received": 3, "published": 2, "rejected": 1}
    with pytest.raises(OSError), open_udp_socket("203.0.113.1", 0):  # not an address of ours
        pass
