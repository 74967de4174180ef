"""``services.heap``: the start-up's objects left out of the garbage collector's traversals, the
youngest generation collected less often, and the objects made after still collected."""

from __future__ import annotations

import gc
import weakref

from ubitrack_agent.services.heap import YOUNG_THRESHOLD, settle_collector


class Node:
    """An object in a reference cycle: only the cyclic collector frees it."""

    def __init__(self) -> None:
        self.me = self


def test_the_start_ups_objects_are_frozen_and_later_cycles_still_collected():
    thresholds = gc.get_threshold()
    before = Node()
    try:
        settle_collector()
        assert gc.get_threshold() == (YOUNG_THRESHOLD, *thresholds[1:])
        assert gc.get_freeze_count() > 0
        frozen = weakref.ref(before)
        after = Node()
        made_after = weakref.ref(after)
        del before, after
        gc.collect()
        assert made_after() is None  # made after the start-up: collected
        assert frozen() is not None  # frozen: never traversed, never freed by the collector
    finally:
        gc.unfreeze()
        gc.set_threshold(*thresholds)
    gc.collect()
    assert frozen() is None  # back in the collector's care
