"""The frame loop of a camera: frames from ``cv2.VideoCapture`` to a camera adapter, with a
periodic one-line status.

``cv2.VideoCapture(index)`` opens a video device (``0`` is the first webcam),
``cv2.VideoCapture(path)`` a video file or an image sequence (``img_%04d.png``);
``read() -> retval, image`` gives the next frame, from a device as it comes and from a file at
the file's frame rate (a recording replays at its own pace, not in a burst). Every frame is
stamped with the time it was read and handed to
:meth:`~ubitrack_agent.io.adapter.SensorAdapter.handle`, which counts a bad one and goes on.
A failed read ends a file; from a device it is counted (``read_failed``) and retried, and
:data:`MAX_FAILED_READS` of them in a row (the device is gone) end the loop too.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import Protocol

import cv2
import numpy as np

from ubitrack_agent.core import CameraIntrinsics
from ubitrack_agent.io.adapter import Publisher
from ubitrack_agent.io.camera.adapter import CameraAdapter
from ubitrack_agent.net.clock import Clock

log = logging.getLogger("ubitrack.camera")

MAX_FAILED_READS = 100
"""Failed reads in a row after which a device counts as gone (about 1 s at the retry pace)."""

RETRY_S = 0.01
"""Pause before reading a device again after a failed read."""

STATUS_INTERVAL_S = 5.0
"""Seconds between two status lines."""


class FrameSource(Protocol):
    """What the loop needs of ``cv2.VideoCapture``."""

    def read(self) -> tuple[bool, np.ndarray | None]: ...


def open_capture(source: str) -> cv2.VideoCapture:
    """A ``cv2.VideoCapture`` of ``source``: a device index if it is all digits, else a file;
    ``OSError`` if OpenCV cannot open it."""
    capture = cv2.VideoCapture(int(source) if source.isdigit() else source)
    if not capture.isOpened():
        capture.release()
        raise OSError(f"OpenCV cannot open {'device' if source.isdigit() else 'file'} {source}")
    return capture


def frame_rate(capture: cv2.VideoCapture) -> float | None:
    """The frame rate ``capture`` reports (``CAP_PROP_FPS``), ``None`` if it reports none."""
    rate = capture.get(cv2.CAP_PROP_FPS)
    return float(rate) if rate > 0 else None


def check_frame_size(capture: cv2.VideoCapture, intrinsics: CameraIntrinsics) -> None:
    """``ValueError`` if ``capture`` reports a frame size other than the intrinsics' (pixels
    of another resolution do not fit the calibration); nothing if either does not tell."""
    size = (int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)))
    expected = intrinsics.image_size
    if expected is not None and min(size) > 0 and size != tuple(expected):
        raise ValueError(
            f"the frames are {size[0]}x{size[1]} px but the intrinsics are for "
            f"{expected[0]}x{expected[1]}: calibrate the camera again at "
            f"{size[0]}x{size[1]} (`ubitrack intrinsics`, docs/camera.md) or set the camera's "
            f"resolution to {expected[0]}x{expected[1]}"
        )


class StatusLine:
    """The one-line status of the loop: frames per second and the markers seen since the last
    line, and the frames rejected so far."""

    def __init__(self, adapter: CameraAdapter, now_s: float) -> None:
        self.adapter = adapter
        self.since_s = now_s
        self.frames = adapter.counters["received"]
        self.seen = Counter(adapter.markers_seen)

    def line(self, now_s: float) -> str:
        """The status since the last call (or since creation), and start a new interval."""
        counters = self.adapter.counters
        rate = (counters["received"] - self.frames) / max(now_s - self.since_s, 1e-9)
        seen = self.adapter.markers_seen - self.seen
        markers = ", ".join(f"{i} x{n}" for i, n in sorted(seen.items())) or "none"
        self.since_s, self.frames = now_s, counters["received"]
        self.seen = Counter(self.adapter.markers_seen)
        return (
            f"camera: {rate:.1f} frames/s, markers seen: {markers}; "
            f"rejected frames: {counters['rejected']}, failed reads: {counters['read_failed']}"
        )


def serve_capture(
    capture: FrameSource,
    adapter: CameraAdapter,
    publisher: Publisher,
    stop: threading.Event,
    from_device: bool,
    duration_s: float | None = None,
    report: Callable[[str], None] | None = None,
    status_every_s: float = STATUS_INTERVAL_S,
    pace_hz: float | None = None,
    clock: Clock | None = None,
) -> None:
    """Read frames from ``capture`` and hand each to ``adapter`` until ``stop`` is set,
    ``duration_s`` has passed, a file ends or a device is gone (see the module docstring),
    at most ``pace_hz`` a second if given (a file's frame rate); pass a :class:`StatusLine`
    to ``report`` every ``status_every_s`` seconds and at the end (``None``: no status). A
    frame is stamped with the time it was read on ``clock`` (the process's: ``net.clock``)."""
    clock = clock or Clock()
    start = time.monotonic()
    status = StatusLine(adapter, start)
    failed_in_a_row = reads = 0
    while not stop.is_set() and (duration_s is None or time.monotonic() - start < duration_s):
        if pace_hz is not None and stop.wait(max(0.0, start + reads / pace_hz - time.monotonic())):
            break
        reads += 1
        ok, image = capture.read()
        received_ns = clock.now_ns()
        if ok and image is not None:
            failed_in_a_row = 0
            adapter.handle(image, received_ns, publisher)
        elif not from_device:
            log.info("camera: end of the file")
            break
        else:
            adapter.counters["read_failed"] += 1
            failed_in_a_row += 1
            if failed_in_a_row >= MAX_FAILED_READS:
                log.warning("camera: %d failed reads in a row; the device is gone", failed_in_a_row)
                break
            stop.wait(RETRY_S)
        now = time.monotonic()
        if report is not None and now - status.since_s >= status_every_s:
            report(status.line(now))
    if report is not None:
        report(status.line(time.monotonic()))
