"""One thread serving the due work of every component of a container.

A worker process running one component gives it a thread that waits for its control commands,
status queries and held triggers (``ubitrack_agent.services.worker``, ``Worker.step``). A container
of a hundred components would run a hundred such threads, each started when its component is
added, each woken on its own; on a loaded machine, creating a component with its threads took
up to 2 s in a process of 80 (issue 28, ``docs/performance.md``, "Time from a query to its
first sample"). A :class:`Scheduler` runs that work for all of them on one thread, as a ROS 2
component container's executor serves its nodes' callbacks and timers: a component's *turn*
(:meth:`Scheduler.wake`: its inbox has something, or its next deadline came; the turn returns
the next one) and calls handed to it from other threads (:meth:`Scheduler.call`, at once or
:meth:`Scheduler.later`: a static input's sample, a value fetched, a retry). Samples of the
dynamic inputs are not its work: each is handled on the thread that takes it
(``net.transport.subscribe_in_bursts``), and handed on in the container on that thread
(``ubitrack_agent.services.local_wires``).

Failure containment: every call is total (an unexpected exception is counted in the
container's ``internal_errors`` and logged; the next call runs). A call that never returns (a
component stuck in a loop on this thread) holds back the turns of every component of the
container, not their data flow; the process is what isolates that (``docs/services.md``,
"Containers").

Growth: one thread per container; a call O(1) to hand over (a C queue), a timer O(log timers);
memory O(components + timers pending).
"""

from __future__ import annotations

import heapq
import itertools
import logging
import queue
import threading
import time
from collections import Counter
from collections.abc import Callable, Hashable
from typing import Any

from ubitrack_agent.net import logs

log = logging.getLogger("ubitrack.container")

Turn = Callable[[], float | None]
"""A component's turn: does what is due, returns when it is next due (monotonic), or None."""


class Scheduler:
    """Runs turns and calls on one thread until :meth:`stop` (module docstring)."""

    def __init__(self, name: str, counters: Counter[str]) -> None:
        self._events: queue.SimpleQueue[tuple[Any, ...] | None] = queue.SimpleQueue()
        self._timers: list[tuple[float, int, Hashable | None, Callable[[], Any]]] = []
        """A heap of (when, sequence, owner, call): a turn's next deadline (its owner's latest
        only, :attr:`_due`) or a call for later (no owner)."""
        self._due: dict[Hashable, float] = {}
        """By owner, when its turn is next due (an earlier timer of it left in the heap is
        skipped)."""
        self._sequence = itertools.count()
        self._counters = counters
        self._name = name
        self._thread = threading.Thread(target=self._run, daemon=True, name=f"turns {name}")
        self._thread.start()

    def wake(self, owner: Hashable, turn: Turn) -> None:
        """Run ``owner``'s ``turn`` soon (any thread; a C call: safe on zenoh's)."""
        self._events.put((owner, turn))

    def call(self, call: Callable[[], Any]) -> None:
        """Run ``call`` soon, on the scheduler's thread (any thread may ask)."""
        self._events.put((None, call))

    def later(self, delay_s: float, call: Callable[[], Any]) -> None:
        """Run ``call`` in ``delay_s`` seconds (from any thread)."""
        self._events.put((None, call, time.monotonic() + delay_s))

    def forget(self, owner: Hashable) -> None:
        """No turn of ``owner`` from its next deadline on (it was removed)."""
        self._events.put((owner, None))

    def stop(self) -> None:
        self._events.put(None)

    def join(self, timeout: float) -> None:
        self._thread.join(timeout)

    @property
    def thread(self) -> threading.Thread:
        return self._thread

    def _run(self) -> None:
        events, timers = self._events, self._timers
        while True:
            timeout = max(0.0, timers[0][0] - time.monotonic()) if timers else None
            try:
                event = events.get(timeout=timeout)
            except queue.Empty:
                event = ()
            batch = [event]
            batch.extend(events.get_nowait() for _ in range(events.qsize()))  # only we take
            for item in batch:
                if item is None:
                    return
                if item:
                    self._take(item)
            now = time.monotonic()
            while timers and timers[0][0] <= now:
                when, _, owner, call = heapq.heappop(timers)
                if owner is None:
                    self._guarded(call)
                elif self._due.get(owner) == when:
                    del self._due[owner]
                    self._turn(owner, call)

    def _take(self, item: tuple[Any, ...]) -> None:
        owner, call = item[0], item[1]
        if len(item) == 3:  # a call for later
            heapq.heappush(self._timers, (item[2], next(self._sequence), None, call))
        elif owner is None:
            self._guarded(call)
        elif call is None:
            self._due.pop(owner, None)
        else:
            self._turn(owner, call)

    def _turn(self, owner: Hashable, turn: Turn) -> None:
        try:
            when = turn()
        except Exception:
            self._fault()
            return
        if when is not None and when < self._due.get(owner, float("inf")):
            self._due[owner] = when
            heapq.heappush(self._timers, (when, next(self._sequence), owner, turn))

    def _guarded(self, call: Callable[[], Any]) -> None:
        try:
            call()
        except Exception:
            self._fault()

    def _fault(self) -> None:
        logs.count_problem(
            self._counters,
            "internal_errors",
            log,
            "%s: internal error on the scheduler's thread",
            self._name,
            exc_info=True,
        )
