"""A few threads taking calls handed over from any thread, started only when needed.

The pattern and its rule for starting a thread are those of the standard library's
``concurrent.futures.ThreadPoolExecutor`` (a thread is started for a call only if no thread is
idle, up to a bound; an idle thread counts itself in a semaphore), without what a call handed
over from zenoh's thread does not need there: no ``Future`` per call (a lock and a condition
to make), no joining at the interpreter's exit (daemon threads: a call still running then is
abandoned). A hand-over costs a C queue's put and a semaphore's try (about 2 us; the
executor's ``submit``, with its ``Future``, took 15-40 us on the same machine), as
``net.transport.LatestValuePublisher`` hands over every query it answers.

Growth: threads O(most) at the most (only as many as were busy at once); memory O(calls
waiting).
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable
from typing import Any


class ThreadPool:
    """At most ``most`` daemon threads named ``<name>-<n>`` running the calls handed to
    :meth:`submit`, oldest first. A call must be total (an exception ends its thread's loop)."""

    def __init__(self, name: str, most: int) -> None:
        self._calls: queue.SimpleQueue[tuple[Callable[[Any], None], Any]] = queue.SimpleQueue()
        self._idle = threading.Semaphore(0)
        """Released by a thread each time it has finished a call (and takes the next)."""
        self._lock = threading.Lock()
        self._started = 0
        self._name = name
        self._most = most

    def submit(self, call: Callable[[Any], None], argument: Any) -> None:
        """Run ``call(argument)`` on a thread of the pool soon (from any thread); starts a
        thread if none is idle and fewer than ``most`` run, else the call waits for one."""
        self._calls.put((call, argument))
        if self._idle.acquire(blocking=False):
            return  # a thread done with its call takes this one
        with self._lock:
            if self._started >= self._most:
                return
            self._started += 1
            number = self._started
        threading.Thread(target=self._run, daemon=True, name=f"{self._name}-{number}").start()

    @property
    def started(self) -> int:
        """Threads started so far (they are kept)."""
        return self._started

    def _run(self) -> None:
        calls, idle = self._calls, self._idle
        while True:
            call, argument = calls.get()
            call(argument)
            idle.release()
