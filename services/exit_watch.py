"""Notice at once that a process ended: Linux process file descriptors, polled on one thread.

The host manager reaps its worker processes in its loop, which waits up to
``host_manager.LOOP_S`` for an event; a container killed between two turns was noticed up to
that much later, and its components restored that much later (issue 28, failure containment).
An :class:`ExitWatch` holds a process file descriptor (``pidfd_open(2)``, Linux 5.3) for each
process it is asked to watch; the descriptor becomes readable when the process ends (killed or
exited, before it is reaped), and the watch calls ``on_exit(pid)`` then, from its thread, so the
host manager's loop wakes and reaps at once. Where process file descriptors are missing (another
system, an older kernel, a process already gone) :meth:`ExitWatch.watch` says so and the loop's
turn still reaps the process. Anchors: ``pidfd_open(2)``, ``poll(2)``; Python's
``os.pidfd_open``.

Growth: one descriptor per watched process; each wake-up O(watched processes) (``poll``).
"""

from __future__ import annotations

import logging
import os
import select
import threading
from collections.abc import Callable

log = logging.getLogger("ubitrack.host")


class ExitWatch:
    """Calls ``on_exit(pid)`` from its own thread as soon as a watched process ends (module
    docstring). :meth:`close` ends the thread and closes every descriptor."""

    def __init__(self, on_exit: Callable[[int], object]) -> None:
        self._on_exit = on_exit
        self._lock = threading.Lock()
        self._watched: dict[int, int] = {}
        """Process file descriptors, by descriptor: the pid."""
        self._poll = select.poll()
        self._wake_read, self._wake_write = os.pipe()
        self._poll.register(self._wake_read, select.POLLIN)
        self._closed = False
        self._thread = threading.Thread(target=self._run, daemon=True, name="exit-watch")
        self._thread.start()

    def watch(self, pid: int) -> bool:
        """Watch process ``pid`` until it ends: True, or False if it cannot be watched (no
        process file descriptors here, or the process is gone)."""
        try:
            fd = os.pidfd_open(pid)
        except (AttributeError, OSError) as exc:
            log.debug("cannot watch process %d for its exit: %s", pid, exc)
            return False
        with self._lock:
            if self._closed:
                os.close(fd)
                return False
            self._watched[fd] = pid
            self._poll.register(fd, select.POLLIN)
        os.write(self._wake_write, b"w")  # poll again, with this descriptor
        return True

    def _run(self) -> None:
        while True:
            ready = self._poll.poll()
            ended = []
            with self._lock:
                if self._closed:
                    return
                for fd, _ in ready:
                    if fd == self._wake_read:
                        os.read(self._wake_read, 4096)
                    elif (pid := self._watched.pop(fd, None)) is not None:
                        self._poll.unregister(fd)
                        os.close(fd)
                        ended.append(pid)
            for pid in ended:
                try:
                    self._on_exit(pid)
                except Exception:  # the watch goes on; the loop's turn reaps the process
                    log.exception("exit of process %d not passed on", pid)

    def close(self) -> None:
        with self._lock:
            self._closed = True
            watched, self._watched = self._watched, {}
        os.write(self._wake_write, b"x")
        self._thread.join(timeout=1.0)
        for fd in watched:
            os.close(fd)
        os.close(self._wake_read)
        os.close(self._wake_write)
