"""What Python's cyclic garbage collector traverses in a worker process.

CPython's collector is generational (the ``gc`` module's documentation; ``Modules/gcmodule.c``):
a full collection, of the oldest generation, traverses every container object the process
holds. A worker process has imported numpy, SciPy, OpenCV, zenoh and every service before it
runs a component: about 70,000 such objects, 25 ms a full collection on the 2-core machine of
``docs/performance.md``. Carrying samples, a process allocates a few dozen objects each, and
the collections that follow cost the containers 14-16 % of their CPU at 20,000 samples/s offered,
each full one holding up every component of the container meanwhile
(``docs/performance.md``, "Throughput, session 22").

The objects of the start-up live as long as the process. :func:`freeze_start_up` moves them to
the collector's permanent generation (``gc.freeze``: "ignore them for all the future
collections", the documented use being a process that has finished its start-up), so that a
collection traverses only what was made since: the components, their buffers and the samples
in flight. Objects made later stay collectable (a component removed from a container leaves no
garbage behind for good). Growth: a full collection O(objects made since), not O(objects of the
imports).
"""

from __future__ import annotations

import gc


def freeze_start_up() -> None:
    """Exempt every object the process holds now from the garbage collector's traversals
    (module docstring): call once the imports are done, before the components are made. No
    collection first: it would cost the start a full one (the start-up's few cycles of garbage
    stay, once)."""
    gc.freeze()
