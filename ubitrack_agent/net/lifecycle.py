"""Ending a process cleanly: SIGTERM and SIGINT (Ctrl-C) run a handler that asks the process's
loop to stop, so it leaves its ``with`` blocks and closes what it declared on zenoh (tokens,
queryables, sessions). One set-up for every long-running process: the agent, host managers,
workers, simulators and sensor adapters."""

from __future__ import annotations

import signal
import threading
from abc import abstractmethod
from collections.abc import Callable
from contextlib import AbstractContextManager


def on_termination(handler: Callable[[], object]) -> None:
    """Call ``handler`` on SIGTERM or SIGINT; it runs in a signal handler, so it must not block
    or take locks (set an event, put on a queue)."""
    signal.signal(signal.SIGTERM, lambda *_: handler())
    signal.signal(signal.SIGINT, lambda *_: handler())


def stop_on_signals() -> threading.Event:
    """An event set by SIGTERM or SIGINT, for a loop that watches it."""
    stop = threading.Event()
    on_termination(stop.set)
    return stop


class Closing(AbstractContextManager):
    """Base of the objects that hold zenoh declarations (providers, relations, stores): a
    context manager whose exit calls :meth:`close`, which must withdraw them and be safe to
    call twice."""

    @abstractmethod
    def close(self) -> None:
        """Withdraw what was declared; a second call does nothing."""

    def __exit__(self, *exc_info: object) -> None:
        self.close()
