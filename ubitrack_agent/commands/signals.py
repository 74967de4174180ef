"""Shutdown of the long-running commands (simulators, sensor adapters): SIGTERM and SIGINT set
an event their loops watch, so they leave their ``with`` blocks and close what they declared."""

from __future__ import annotations

import signal
import threading


def stop_on_signals() -> threading.Event:
    """An event set by SIGTERM or SIGINT, so a long-running loop can end and clean up."""
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    return stop
