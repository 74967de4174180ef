"""A worker process's host manager, watched through the pipe it gives the process as standard
input (``ubitrack_agent.services.supervisor``): the pipe closes when the host manager ends, however
it ends (SIGTERM, SIGKILL, or with the agent that started it).

What the process does once its host manager is gone depends on where its run stands
(``docs/protocol.md``, "When the host manager is gone"):

* **starting**, from its spawn (or from taking a specification in the pool) until its worker
  token is up: it exits at once, wherever it is (importing numpy, scipy and OpenCV, opening
  its session, subscribing). It serves nothing yet and nobody owns it: the host manager that
  would stop it or report its end is gone, and the agent starts the instance again where
  placement says (a restarted agent, once it has settled). Finishing the start would cost a
  cold start's imports on a machine busy recovering, only to run as a duplicate that the agent
  then stops: under load such processes were still importing 40 s later (chaos seed 210,
  ``docs/reliability.md``);
* **serving**, its token up: it keeps running, so that a restarted agent adopts it and the
  applications keep their data; released, it exits instead of returning to the pool (a
  container, once its last component has left);
* **idle** in the pool: it leaves the pool and exits.

A worker whose host manager dies just as it declares its token is either starting or serving,
never both: the watcher decides under the lock that the declaration holds.
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Callable
from typing import TypeVar

log = logging.getLogger("ubitrack.worker")

T = TypeVar("T")


class Parent:
    """The host manager that started this process (see the module docstring), watched on a
    thread reading ``fd`` (standard input); ``exit_process`` ends the process while it is
    starting."""

    def __init__(self, fd: int = 0, exit_process: Callable[[int], object] = os._exit) -> None:
        self._gone = False
        self._fd = fd
        self._exit = exit_process
        self._lock = threading.Lock()
        self._starting = True
        self._wake: Callable[[], None] = lambda: None
        threading.Thread(target=self._watch, daemon=True, name="parent").start()

    def _watch(self) -> None:
        try:
            while os.read(self._fd, 4096):  # no buffered reader: its lock would hold up exit
                pass
        except OSError:
            pass  # no standard input to read: as good as closed
        with self._lock:
            if self._starting:
                log.warning("host manager gone while this worker was starting: exiting")
                self._exit(0)
                return
            self._gone = True
            wake = self._wake
        wake()

    @property
    def gone(self) -> bool:
        """Whether the host manager is gone (a container left without a component then
        ends: nobody else would stop it)."""
        with self._lock:
            return self._gone

    def when_gone(self, wake: Callable[[], None]) -> None:
        """Call ``wake`` (from the watching thread) when the host manager goes from now on while
        the process is idle or serving (:meth:`idle` tells whether it went before)."""
        with self._lock:
            self._wake = wake

    def idle(self) -> bool:
        """The process waits in the pool: True, or False if the host manager is gone (the
        process should end)."""
        with self._lock:
            self._starting = False
            return not self._gone

    def start(self) -> bool:
        """The process took a specification in the pool and starts running it: True, or False
        if the host manager is gone (the process should end instead)."""
        with self._lock:
            if self._gone:
                return False
            self._starting = True
            return True

    def serve(self, declare: Callable[[], T]) -> T:
        """Declare the run's worker token with ``declare`` and return it: from then on the
        process outlives its host manager."""
        with self._lock:
            token = declare()
            self._starting = False
        return token
