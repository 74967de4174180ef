"""``ubitrack demo``: a tracker and an application on an embedded zenoh network.

This process is the zenoh hub (peer mode, loopback, no router). It starts a simulated
outside-in tracker (:mod:`sim_trackers.pose_publisher`) as a separate process, which measures
``ART->HT`` (a moving head target) and ``ART->WT`` (a static world target). The application
side subscribes to both, validates every message, and derives ``WT->HT`` by the paper's two
basic patterns, inversion and concatenation (section 3.1), propagating covariances. Once a
second it prints the derived pose, its rate, its latency, its error against ground truth and
the error the propagated covariance predicts. With ``--json`` each report is one JSON line.
"""

from __future__ import annotations

import argparse
import json
import queue
import subprocess
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from .. import config
from ..core import ErrorPose, MeasurementError, Position3D, decode, se3
from ..core.poses import compose_poses, invert_pose, transform_position
from ..keys import KeySpace


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "demo",
        help="run a simulated tracker and an application deriving a relation from it",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--duration", type=float, default=6.0, help="seconds to run (default: %(default)s)"
    )
    parser.add_argument("--rate", type=float, default=60.0, help="tracker rate in Hz")
    parser.add_argument("--json", action="store_true", help="print JSON lines instead of text")
    config.add_arguments(parser)
    parser.set_defaults(func=run)


@dataclass
class Report:
    """Statistics of one reporting interval (or of the whole run)."""

    samples: int = 0
    rejected: int = 0
    latencies_ms: list[float] = field(default_factory=list)
    errors_mm: list[float] = field(default_factory=list)
    predicted_mm: list[float] = field(default_factory=list)
    last: ErrorPose | None = None

    def summary(self, seconds: float) -> dict[str, float | int | None]:
        def median(values: list[float]) -> float | None:
            return round(float(np.median(values)), 3) if values else None

        def rms(values: list[float]) -> float | None:
            return round(float(np.sqrt(np.mean(np.square(values)))), 3) if values else None

        return {
            "samples": self.samples,
            "rejected": self.rejected,
            "rate_hz": round(self.samples / seconds, 1) if seconds > 0 else None,
            "latency_ms_median": median(self.latencies_ms),
            "error_mm_rms": rms(self.errors_mm),
            "predicted_error_mm_rms": rms(self.predicted_mm),
        }


def _tracker_command(settings: config.Settings, rate: float) -> list[str]:
    hub = settings.listen[0]
    return [
        sys.executable,
        "-m",
        "sim_trackers.pose_publisher",
        "--rate",
        str(rate),
        "--connect",
        hub,
        "--listen",
        "tcp/127.0.0.1:0",
        "--prefix",
        settings.prefix,
        "--domain",
        settings.domain,
    ]


def _position_error_mm(derived: ErrorPose) -> tuple[float, float]:
    """Error of the derived HT origin against ground truth, and its predicted RMS, in mm."""
    from sim_trackers.pose_publisher import REFERENCE_POSE
    from sim_trackers.trajectories import LissajousPath

    q_ref, t_ref = se3.invert(*REFERENCE_POSE)
    truth = se3.compose(q_ref, t_ref, *LissajousPath().pose(derived.timestamp_ns * 1e-9))[1]
    origin = transform_position(derived, Position3D(derived.timestamp_ns, np.zeros(3)))
    error = float(np.linalg.norm(origin.position - truth)) * 1000.0
    predicted = float(np.sqrt(np.trace(origin.covariance))) * 1000.0
    return error, predicted


def run(args: argparse.Namespace) -> int:
    import zenoh

    from ..session import open_session

    settings = config.from_arguments(args, role="hub")
    if not settings.listen:
        print("ubitrack demo: the hub needs a --listen endpoint", file=sys.stderr)
        return 2
    keys = KeySpace(settings.key_prefix)
    inbox: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
    try:
        session = open_session(settings)
    except zenoh.ZError as exc:
        print(f"ubitrack demo: cannot open zenoh on {settings.listen}: {exc}", file=sys.stderr)
        return 2
    tracker = None
    try:
        # The callback only queues (never call zenoh from a zenoh callback).
        subscribers = [
            session.declare_subscriber(
                keys.data(edge),
                lambda sample: inbox.put((str(sample.key_expr), sample.payload.to_bytes())),
            )
            for edge in ("ART/HT", "ART/WT")
        ]
        tracker = subprocess.Popen(_tracker_command(settings, args.rate))
        total = _consume(args, keys, inbox, tracker)
        for subscriber in subscribers:
            subscriber.undeclare()
    finally:
        if tracker is not None:
            tracker.terminate()
            try:
                tracker.wait(timeout=5)
            except subprocess.TimeoutExpired:
                tracker.kill()
                tracker.wait()
        session.close()
    summary = total.summary(args.duration)
    _print(args.json, {"event": "summary", **summary}, "summary")
    if tracker.returncode not in (0, -15):
        print(f"ubitrack demo: tracker exited with {tracker.returncode}", file=sys.stderr)
        return 1
    return 0 if total.samples else 1


def _consume(args, keys: KeySpace, inbox, tracker) -> Report:
    body_key, reference_key = keys.data("ART/HT"), keys.data("ART/WT")
    reference: ErrorPose | None = None
    total, interval = Report(), Report()
    start = last_report = time.monotonic()
    while (now := time.monotonic()) - start < args.duration:
        if tracker.poll() is not None:
            break
        if now - last_report >= 1.0:
            _report(args.json, interval, now - last_report, reference)
            interval, last_report = Report(), now
        try:
            key, payload = inbox.get(timeout=0.05)
        except queue.Empty:
            continue
        try:
            measurement = decode(payload, expected=ErrorPose)
        except MeasurementError as exc:
            print(f"rejected sample on {key}: {exc}", file=sys.stderr)
            total.rejected += 1
            interval.rejected += 1
            continue
        if key == reference_key:
            reference = measurement
        elif key == body_key and reference is not None:
            derived = compose_poses(invert_pose(reference), measurement)
            latency = (time.time_ns() - measurement.timestamp_ns) / 1e6
            error, predicted = _position_error_mm(derived)
            for report in (total, interval):
                report.samples += 1
                report.latencies_ms.append(latency)
                report.errors_mm.append(error)
                report.predicted_mm.append(predicted)
            interval.last = derived
    return total


def _report(as_json: bool, report: Report, seconds: float, reference) -> None:
    data = {"event": "report", "relation": "WT->HT", **report.summary(seconds)}
    if report.last is not None:
        data["translation_m"] = [round(float(v), 4) for v in report.last.translation]
        data["rotation_xyzw"] = [round(float(v), 4) for v in report.last.rotation]
    elif reference is None:
        data["waiting_for"] = "ART->WT"
    _print(as_json, data, "WT->HT")


def _print(as_json: bool, data: dict, title: str) -> None:
    if as_json:
        print(json.dumps(data), flush=True)
        return
    parts = [f"{k}={v}" for k, v in data.items() if k != "event"]
    print(f"{title:>8}: " + "  ".join(parts), flush=True)
