"""How often Python's cyclic garbage collector runs, and what it traverses: in a worker process
(:func:`settle_collector`) and while the planner runs (:func:`collector_paused`).

CPython's collector is generational (the ``gc`` module's documentation; ``Modules/gcmodule.c``):
the youngest generation is collected once the container objects allocated and not freed since
its last collection exceed a threshold (700 by default), survivors move up, and every tenth
collection of a generation collects the next as well, the oldest one traversing every container
object the process holds. A worker process carrying a backlog holds its samples' objects alive
for the run (decoded messages, measurements, their ``__dict__``\\s: a few dozen a sample), so at
700 the collector ran a young collection every few samples and carried the run up into the older
generations: at 20,000 samples/s offered it took 14-16 % of the containers' CPU (``perf``),
2,000 collections in 30 s with 17 of the oldest generation, 0.1-0.2 s each on the loaded 2-core
machine, every component of the container held up meanwhile (``docs/performance.md``,
"Throughput, session 22"). What the data path allocates is freed by reference counting as soon
as a sample has passed: those collections found about 1,300 objects in cycles in a container
that carried some 125,000 samples. So a young collection is only worth it after
:data:`YOUNG_THRESHOLD` allocations not freed (6-8 collections in the same run, none older).

And the objects of the start-up (modules, functions, classes of numpy, SciPy, OpenCV, zenoh and
every service: about 70,000, 25 ms to traverse) live as long as the process:
:func:`settle_collector` moves them to the collector's permanent generation (``gc.freeze``:
"ignore them for all the future collections", meant for a process that has finished its
start-up), so a collection of the oldest generation traverses only what was made since. Objects
made later stay collectable (a component removed from a container leaves no garbage behind for
good). Growth: a collection O(objects made since the start-up and alive), at most one per
:data:`YOUNG_THRESHOLD` allocations not freed.

The planner is the same case in one call: a plan builds its working SRG (records, steps,
frozensets of sources: about 320 container objects a tracker in a room, 160,000 at 500) and
keeps all of it until it returns, so the collector ran every 700 of them, moved them up and
traversed them again in the older generations: a fifth to a third of a plan's CPU in a room of
200-1,000 trackers, a share that grows with the plan (``docs/performance.md``, "Planner,
session 28"). A plan's
objects form no reference cycle (``tests/unit/test_planner_bounds.py`` checks that a plan leaves
nothing to the collector), so reference counting frees them all when it returns, and the
collector finds nothing of the plan's to collect: :func:`collector_paused` keeps it off for the
plan's duration. It is process-wide (CPython has one collector): other threads' cyclic garbage
waits for the plan's end, at most one plan's time.
"""

from __future__ import annotations

import gc
import threading
from collections.abc import Iterator
from contextlib import contextmanager

YOUNG_THRESHOLD = 50_000
"""Container objects allocated and not freed after which the youngest generation is collected
(CPython's default: 700); the older generations' thresholds stay CPython's."""


def settle_collector() -> None:
    """Collect the youngest generation after :data:`YOUNG_THRESHOLD` allocations, and exempt
    every object the process holds now from the collector's traversals (module docstring): call
    once the imports are done, before the components are made. No collection first: it would
    cost the start a full one (the start-up's few cycles of garbage stay, once)."""
    _, middle, oldest = gc.get_threshold()
    gc.set_threshold(YOUNG_THRESHOLD, middle, oldest)
    gc.freeze()


class _Pauses:
    """How many :func:`collector_paused` blocks run now (any thread), and whether the collector
    was on when the first began."""

    lock = threading.Lock()
    running = 0
    resume = False


@contextmanager
def collector_paused() -> Iterator[None]:
    """The cyclic collector off while the block runs (module docstring), on again when the
    last of the blocks running at once in any thread ends, if it was on when the first began.
    For work that keeps what it allocates alive until it ends and leaves no cycle behind."""
    with _Pauses.lock:
        if _Pauses.running == 0:
            _Pauses.resume = gc.isenabled()
            gc.disable()
        _Pauses.running += 1
    try:
        yield
    finally:
        with _Pauses.lock:
            _Pauses.running -= 1
            if _Pauses.running == 0 and _Pauses.resume:
                gc.enable()
