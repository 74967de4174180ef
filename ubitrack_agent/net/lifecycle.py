"""Ending a process cleanly: SIGTERM and SIGINT (Ctrl-C) run a handler that asks the process's
loop to stop, so it leaves its ``with`` blocks and closes what it declared on zenoh (tokens,
queryables, sessions). One set-up for every long-running process: the agent, host managers,
workers, simulators and sensor adapters."""

from __future__ import annotations

import logging
import queue
import signal
import threading
from abc import abstractmethod
from collections.abc import Callable
from contextlib import AbstractContextManager

log = logging.getLogger("ubitrack.lifecycle")

_requests: queue.SimpleQueue[int] = queue.SimpleQueue()
_handler: list[Callable[[], object]] = []
"""The handler :func:`on_termination` registered last (empty before the first call)."""


def _run_handlers() -> None:
    while True:
        signum = _requests.get()
        try:
            _handler[-1]()
        except Exception:  # a failing handler must not end the thread: a second signal may work
            log.exception("the handler of signal %d failed", signum)


def on_termination(handler: Callable[[], object]) -> None:
    """Call ``handler`` on SIGTERM or SIGINT, on a thread of its own (one per process); a
    later call replaces the handler.

    Python runs a signal handler on the main thread between two bytecodes, possibly while that
    thread holds the very lock the handler needs: ``Event.set`` from a handler deadlocks when
    the signal arrives as the main thread enters or leaves ``Event.wait`` (a simulator once hung
    on SIGTERM so). The signal handler therefore only puts on a :class:`queue.SimpleQueue`,
    whose ``put`` the standard library documents as reentrant, safe in signal handlers, and the
    handler runs on the thread that takes from it, where waiting for a lock is harmless."""
    if _handler:
        _handler[-1] = handler
    else:
        _handler.append(handler)
        threading.Thread(target=_run_handlers, daemon=True, name="termination").start()
    signal.signal(signal.SIGTERM, lambda signum, _: _requests.put(signum))
    signal.signal(signal.SIGINT, lambda signum, _: _requests.put(signum))


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
