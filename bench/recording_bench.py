"""``ubitrack record`` and ``ubitrack replay`` (``ubitrack_agent.io.recording``): samples per
second, added latency per sample, and the figure-1 calibration on a replay (issue 30).

Run: ``python -m bench.recording_bench [--samples N] [--seconds S] [--figure1-seconds S]``
(defaults 20,000, 5 and 30; about two minutes). Prints the figures and writes
``bench/results/recording.json``. On loopback, with real zenoh sessions and processes:

* **writer / reader:** the file alone, in this process: ``N`` 6D samples with covariance written
  (the msgpack bytes and a ``foxglove.FrameTransform`` each) and read back checked;
* **record, paced:** a provider in this process publishes a 6D edge at 1 kHz for ``S`` s while
  ``ubitrack record`` (another process) records it; latency is the recorder's log time minus
  the sample's timestamp (its publish time); lost = published - recorded;
* **record, flat out:** ``N`` samples published back to back: samples/s recorded and lost;
* **replay, paced:** the paced file replayed at speed 1 by :class:`Replayer` in this process,
  read by a subscriber here: the added latency of a sample is when it arrived minus when it
  was due (the recording's spacing from the replay's start), and the scheduler's own lateness;
* **replay, flat out:** the flat-out file at ``--speed 1000``: samples/s published (its samples
  are due faster than they can go, so no latency is quoted);
* **figure 1:** the demo's sensors recorded for ``--figure1-seconds`` while ``C -> HT`` is
  calibrated live, then replayed into a fresh agent with no simulator and calibrated again:
  the two results' difference, and ``C -> A`` samples on the replay
  (``tests/integration/recording_helpers.py``).
"""

from __future__ import annotations

import argparse
import io
import os
import platform
import queue
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.dataflow_bench import percentiles
from bench.report import write_results
from tests.integration.conftest import end_groups
from tests.integration.recording_helpers import difference, record_live, replay_into_fresh_agent
from tests.integration.zenoh_helpers import free_port, hub_session, member_flags
from ubitrack_agent.core import ErrorPose, decode, encode
from ubitrack_agent.io.provider import EdgeAnnouncement, Provider
from ubitrack_agent.io.recording.fragments import Announced
from ubitrack_agent.io.recording.reader import Sample, read_recording
from ubitrack_agent.io.recording.replayer import Replayer
from ubitrack_agent.io.recording.writer import RecordingWriter
from ubitrack_agent.net.keys import KeySpace

RESULTS = Path(__file__).with_name("results") / "recording.json"
EDGE = EdgeAnnouncement("T", "HT", "6D", rate=1000.0)
PACED_HZ = 1000.0


def pose(t: int, i: int) -> ErrorPose:
    angle = i * 1e-3
    q = np.array([0.0, 0.0, np.sin(angle / 2), np.cos(angle / 2)])
    return ErrorPose(t, q, np.array([i * 1e-4, 0.25, -1 / 3]), np.eye(6) * 1e-6)


def file_alone(samples: int) -> dict[str, Any]:
    values = [pose(1_000 + i, i) for i in range(samples)]
    payloads = [encode(v) for v in values]
    stream = io.BytesIO()
    writer = RecordingWriter(stream)
    writer.announced(Announced("p", "lab", (EDGE,)))
    started = time.perf_counter()
    for payload, value in zip(payloads, values, strict=True):
        writer.measured("p", EDGE.name, payload, value)
    writer.finish()
    wrote = time.perf_counter() - started
    data = stream.getvalue()
    started = time.perf_counter()
    read = sum(isinstance(e, Sample) for e in read_recording(io.BytesIO(data)))
    reading = time.perf_counter() - started
    assert read == samples
    return {
        "samples": samples,
        "bytes_per_sample": round(len(data) / samples, 1),
        "written_per_s": round(samples / wrote),
        "write_us_per_sample": round(wrote / samples * 1e6, 1),
        "read_checked_per_s": round(samples / reading),
        "read_us_per_sample": round(reading / samples * 1e6, 1),
    }


def record(port: int, domain: str, path: Path, publish) -> tuple[list[bytes], list[Sample]]:
    """``ubitrack record`` of what ``publish(provider)`` publishes: (published, recorded)."""
    keys = KeySpace(f"ubitrack/{domain}")
    command = ["record", str(path), "--json", "--quiet", *member_flags(port, domain)]
    recorder = subprocess.Popen(
        [sys.executable, "-m", "ubitrack_agent.cli", *command],
        stdout=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        with hub_session(port) as session, Provider(session, keys, "p", [EDGE]) as provider:
            assert '"announced"' in recorder.stdout.readline()
            time.sleep(0.5)  # the recorder's subscription reaches this session
            published = publish(provider)
            time.sleep(1.0)
        recorder.send_signal(signal.SIGINT)
        recorder.communicate(timeout=60)
    finally:
        end_groups([recorder])
    with path.open("rb") as stream:
        recorded = [e for e in read_recording(stream) if isinstance(e, Sample)]
    return published, recorded


def paced(provider: Provider, seconds: float) -> list[bytes]:
    published, period = [], 1e9 / PACED_HZ
    start = time.monotonic_ns()
    for i in range(int(seconds * PACED_HZ)):
        wait = start + i * period - time.monotonic_ns()
        if wait > 0:
            time.sleep(wait / 1e9)
        value = pose(time.time_ns(), i)
        provider.publish(EDGE.name, value)
        published.append(encode(value))
    return published


def flat_out(provider: Provider, samples: int) -> list[bytes]:
    published = []
    for i in range(samples):
        value = pose(time.time_ns(), i)
        provider.publish(EDGE.name, value)
        published.append(encode(value))
    return published


def recording_figures(published: list[bytes], recorded: list[Sample]) -> dict[str, Any]:
    latency_us = [(s.log_time_ns - s.measurement.timestamp_ns) / 1e3 for s in recorded]
    span = (recorded[-1].log_time_ns - recorded[0].log_time_ns) / 1e9
    exact = [encode(s.measurement) for s in recorded] == published[-len(recorded) :]
    return {
        "published": len(published),
        "recorded": len(recorded),
        "lost": len(published) - len(recorded),
        "gapless_and_bit_exact": exact,
        "recorded_per_s": round(len(recorded) / span) if span > 0 else None,
        "latency_us": percentiles(latency_us),
    }


def replay(port: int, domain: str, path: Path, speed: float) -> dict[str, Any]:
    """Replay ``path`` in this process at ``speed``, received by a subscriber here."""
    keys = KeySpace(f"ubitrack/{domain}")
    with path.open("rb") as stream:
        events = list(read_recording(stream))
    recorded_log = {
        e.measurement.timestamp_ns: e.log_time_ns for e in events if isinstance(e, Sample)
    }
    first_log = events[0].log_time_ns
    arrivals: queue.SimpleQueue[tuple[int, bytes]] = queue.SimpleQueue()
    with hub_session(port) as session:
        subscriber = session.declare_subscriber(
            keys.measured("p", EDGE.name),
            lambda s: arrivals.put((time.time_ns(), s.payload.to_bytes())),
        )
        replayer = Replayer(session, keys, "lab", speed, True, threading.Event(), measure=True)
        time.sleep(0.5)
        with replayer:
            started = time.perf_counter()
            replayer.play(events)
            elapsed = time.perf_counter() - started
            time.sleep(1.0)
        subscriber.undeclare()
    added_us = []
    received = 0
    while not arrivals.empty():
        arrived, payload = arrivals.get_nowait()
        received += 1
        shifted = decode(payload).timestamp_ns
        log_time = recorded_log[shifted - replayer.offset_ns]
        due_wall = first_log + replayer.offset_ns + round((log_time - first_log) / speed)
        added_us.append((arrived - due_wall) / 1e3)
    published = replayer.counters["published"]
    figures = {
        "speed": speed,
        "published": published,
        "received": received,
        "recording_span_s": round((events[-1].log_time_ns - first_log) / 1e9, 3),
        "replay_s": round(elapsed, 3),
        "published_per_s": round(published / elapsed),
    }
    if speed == 1.0:  # faster, samples are due sooner than they can go: a backlog, not latency
        figures["added_latency_us"] = percentiles(added_us)
        figures["scheduler_lateness_us"] = percentiles([n / 1e3 for n in replayer.lateness_ns])
    return figures


def figure1(seconds: float, folder: Path) -> dict[str, Any]:
    processes: list[subprocess.Popen] = []
    path = folder / "figure1.mcap"
    try:
        live = record_live(processes, path, seconds)
        replayed = replay_into_fresh_agent(processes, path)
    finally:
        end_groups(processes)
    mm, deg = difference(live["calibration"]["value"], replayed["calibration"]["value"])
    finished = live["recorder"][-1]
    return {
        "recorded_s": round(live["seconds"], 1),
        "file_bytes": finished["bytes"],
        "measurements": finished["measurements"],
        "live_calibration_s": round(live["calibration"]["seconds"], 1),
        "replay_calibration_s": round(replayed["calibration"]["seconds"], 1),
        "difference_mm": round(mm, 3),
        "difference_deg": round(deg, 4),
        "c_a_samples_in_3_s": replayed["tracked_samples"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--samples", type=int, default=20_000)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument(
        "--figure1-seconds", type=float, default=30.0, help="0 leaves the figure-1 run out"
    )
    args = parser.parse_args()
    results: dict[str, Any] = {
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "load_average_1min_at_start": round(os.getloadavg()[0], 2),
        },
        "command": "python -m bench.recording_bench " + " ".join(sys.argv[1:]),
        "file_alone": file_alone(args.samples),
    }
    with tempfile.TemporaryDirectory(prefix="recording-bench-") as scratch:
        folder = Path(scratch)
        port = free_port()
        domain = f"recbench{port}"
        paced_file, flat_file = folder / "paced.mcap", folder / "flat.mcap"
        results["record_paced_1khz"] = recording_figures(
            *record(port, domain, paced_file, lambda p: paced(p, args.seconds))
        )
        results["record_flat_out"] = recording_figures(
            *record(port, domain, flat_file, lambda p: flat_out(p, args.samples))
        )
        results["replay_paced_speed_1"] = replay(port, domain, paced_file, 1.0)
        results["replay_flat_out_speed_1000"] = replay(port, domain, flat_file, 1000.0)
        if args.figure1_seconds > 0:
            results["figure1"] = figure1(args.figure1_seconds, folder)
    write_results(RESULTS, results)


if __name__ == "__main__":
    main()
