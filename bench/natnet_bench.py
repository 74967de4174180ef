"""Cost of the NatNet adapter (:mod:`ubitrack_agent.io.natnet`): packets parsed per second and
the latency it adds per sample.

Run: ``python -m bench.natnet_bench [--packets N]`` (default 3000 per cell). Three parts:

1. **Parse rate**, per NatNet version (3.1, 4.1) and rigid bodies per frame (1, 2, 10, 50):
   frames built by :func:`~ubitrack_agent.io.natnet.format.build_frame` are parsed by
   ``parse_frame`` alone, and by the adapter's ``handle`` (parse, convert to ``ErrorPose``
   with covariance, hand to a publisher that keeps nothing); side by side, the PyPI client
   ``natnet`` 0.3's own frame reader on the same packets (when installed). Packets per CPU
   second (the machine's cores are shared), medians of five runs; the cost over bodies shows
   the growth (O(n) in rigid bodies).
2. **Added latency per sample**: the adapter's ``handle`` CPU time per frame of the demo's
   two bodies (median and 90th percentile over N frames), i.e. the time from a datagram in
   hand to its measurements handed to the provider.
3. **Over loopback UDP**: ``ubitrack sim natnet``'s server sends N frames (unicast, NatNet
   4.1) to a :class:`~ubitrack_agent.io.natnet.link.NatNetLink` in this process; the time
   from each frame's ``sendto`` to its first measurement reaching the publisher (median,
   90th percentile): socket, select loop, parse and conversion.

Writes ``bench/results/natnet.json``. Zenoh's own publish cost is measured by
``bench/hop_cost_bench.py`` and is not included.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import socket
import statistics
import threading
import time
from pathlib import Path

import numpy as np

from bench.report import write_results
from ubitrack_agent.io.natnet import format as natnet
from ubitrack_agent.io.natnet.adapter import NatNetAdapter
from ubitrack_agent.io.natnet.format import Frame, NatNetVersion, RigidBody, ServerInfo
from ubitrack_agent.io.natnet.link import NatNetLink
from ubitrack_agent.sim_trackers.scenario import load_scenario
from ubitrack_agent.sim_trackers.sim_natnet import NatNetServer, NatNetSimulator, body_names

RESULTS = Path(__file__).parent / "results" / "natnet.json"
VERSIONS = (NatNetVersion(3, 1), NatNetVersion(4, 1))
BODY_COUNTS = (1, 2, 10, 50)
RUNS = 5


class Discard:
    def publish(self, edge_name, measurement) -> None:
        pass


def _frame(bodies: int, rng: np.random.Generator) -> Frame:
    rotations = rng.normal(size=(bodies, 4))
    rotations /= np.linalg.norm(rotations, axis=1, keepdims=True)
    return Frame(
        7,
        tuple(
            RigidBody(i + 1, tuple(rng.uniform(-2, 2, 3)), tuple(rotations[i]), 0.0004, True)
            for i in range(bodies)
        ),
        12.5,
        1000,
        1500,
        2000,
    )


def _adapter(bodies: int, version: NatNetVersion) -> NatNetAdapter:
    adapter = NatNetAdapter("OT", body_ids={i + 1: f"B{i + 1}" for i in range(bodies)})
    info = ServerInfo("Motive", NatNetVersion(3, 1), version, 10_000_000, 1511, False)
    adapter.handle(natnet.build_server_info(info), 0, Discard())
    return adapter


def _rate(work, packets: int) -> float:
    """Packets per CPU second of this process: the median of :data:`RUNS` runs of ``work``
    over ``packets`` (CPU time, not wall time, as the 2 cores are shared with other work)."""
    rates = []
    for _ in range(RUNS):
        started = time.process_time()
        for _ in range(packets):
            work()
        rates.append(packets / (time.process_time() - started))
    return statistics.median(rates)


def parse_rates(packets: int) -> list[dict]:
    try:
        from natnet.data_frame import DataFrame as TheirFrame
        from natnet.packet_buffer import PacketBuffer
        from natnet.version import Version as TheirVersion
    except ImportError:
        TheirFrame = None
    rng = np.random.default_rng(1)
    rows = []
    for version in VERSIONS:
        for bodies in BODY_COUNTS:
            packet = natnet.build_frame(_frame(bodies, rng), version)
            payload = natnet.split_packet(packet)[1]
            adapter, sink = _adapter(bodies, version), Discard()
            row = {
                "version": str(version),
                "rigid_bodies": bodies,
                "packet_bytes": len(packet),
                "parse_packets_per_s": round(
                    _rate(lambda p=payload, v=version: natnet.parse_frame(p, v), packets)
                ),
                "adapter_packets_per_s": round(
                    _rate(lambda a=adapter, p=packet, s=sink: a.handle(p, 0, s), packets)
                ),
            }
            assert adapter.counters["published"] == bodies * packets * RUNS
            if TheirFrame is not None:
                theirs = TheirVersion(*version)

                def their_parse(p=packet, v=theirs) -> None:
                    buffer = PacketBuffer(p)
                    buffer.read("HH")
                    TheirFrame.read_from_buffer(buffer, v)

                row["pypi_natnet_parse_packets_per_s"] = round(_rate(their_parse, packets))
            rows.append(row)
            print(row)
    return rows


def _percentiles(values_ns: list[int]) -> dict[str, float]:
    return {
        "median_us": round(statistics.median(values_ns) / 1e3, 1),
        "p90_us": round(float(np.percentile(values_ns, 90)) / 1e3, 1),
    }


def handle_latency(packets: int) -> dict:
    scenario = load_scenario()
    art = dataclasses.replace(scenario.art, dropout=0.0)
    simulator = NatNetSimulator(scenario.world, art, np.random.default_rng(2))
    adapter = NatNetAdapter(art.frame, body_names(art), static_bodies=art.static_bodies)
    info = ServerInfo("Motive", NatNetVersion(3, 1), NatNetVersion(4, 1), 10**9, 1511, False)
    adapter.handle(natnet.build_server_info(info), 0, Discard())
    adapter.handle(
        natnet.build_model_definitions(simulator.descriptions(), info.natnet_version), 0, Discard()
    )
    times = []
    for i in range(packets):
        packet = natnet.build_frame(simulator.frame(i, i), info.natnet_version)
        started = time.thread_time_ns()
        adapter.handle(packet, 0, Discard())
        times.append(time.thread_time_ns() - started)
    assert adapter.counters["published"] == 2 * packets
    return {"rigid_bodies": 2, "frames": packets, **_percentiles(times)}


class FirstArrival:
    """Keeps, per frame, when its first measurement reached the publisher."""

    def __init__(self) -> None:
        self.arrivals: list[int] = []
        self.count = 0
        self.frame_done = threading.Event()

    def publish(self, edge_name, measurement) -> None:
        self.count += 1
        if self.count % 2 == 1:  # the first of the frame's two bodies
            self.arrivals.append(time.perf_counter_ns())
        else:
            self.frame_done.set()


def loopback_latency(packets: int) -> dict:
    scenario = load_scenario()
    art = dataclasses.replace(scenario.art, dropout=0.0)
    simulator = NatNetSimulator(scenario.world, art, np.random.default_rng(3))
    adapter = NatNetAdapter(art.frame, body_names(art), static_bodies=art.static_bodies)
    sink, stop = FirstArrival(), threading.Event()
    with NatNetServer(simulator, "127.0.0.1", 0, 0, NatNetVersion(4, 1)) as server:
        command_port = server.command.getsockname()[1]
        serving = threading.Thread(target=server.serve_commands, args=(stop,))
        serving.start()
        with NatNetLink("127.0.0.1", command_port, 0, None, "127.0.0.1") as link:
            client = threading.Thread(target=link.serve, args=(adapter, sink, stop))
            client.start()
            deadline = time.monotonic() + 10
            while not (adapter.names and server.clients) and time.monotonic() < deadline:
                time.sleep(0.01)
            (address,) = server.clients
            sent = []
            for i in range(packets):
                packet = natnet.build_frame(simulator.frame(i, i), server.version)
                sink.frame_done.clear()
                sent.append(time.perf_counter_ns())
                server.data.sendto(packet, address)
                sink.frame_done.wait(timeout=5)  # one frame in flight at a time
            stop.set()
            client.join()
        serving.join()
    assert len(sink.arrivals) == packets, (len(sink.arrivals), dict(adapter.counters))
    return {
        "rigid_bodies": 2,
        "frames": packets,
        "transport": "unicast UDP on 127.0.0.1, NatNet 4.1",
        **_percentiles([a - s for a, s in zip(sink.arrivals, sent, strict=True)]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--packets", type=int, default=3000, help="packets per cell")
    args = parser.parse_args()
    results = {
        "bench": "natnet",
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count()},
        "packets_per_cell": args.packets,
        "parse": parse_rates(args.packets),
        "handle_latency": handle_latency(args.packets),
        "loopback_latency": loopback_latency(min(args.packets, 2000)),
        "socket_family": socket.AF_INET.name,
    }
    write_results(RESULTS, results)


if __name__ == "__main__":
    main()
