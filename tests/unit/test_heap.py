"""``core.heap``: the start-up's objects left out of the garbage collector's traversals, the
youngest generation collected less often, and the objects made after still collected; the
collector paused while blocks run in any thread, and on again after the last."""

from __future__ import annotations

import gc
import threading
import weakref

from ubitrack_agent.core.heap import YOUNG_THRESHOLD, collector_paused, settle_collector


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


def test_the_collector_is_paused_until_the_last_block_of_any_thread_ends():
    assert gc.isenabled()
    first_in, second_out = threading.Event(), threading.Event()
    seen = []

    def other_thread() -> None:
        with collector_paused():
            first_in.set()
            second_out.wait(5)
            seen.append(gc.isenabled())  # the main thread's block has ended: still paused
        seen.append(gc.isenabled())

    with collector_paused():
        thread = threading.Thread(target=other_thread)
        thread.start()
        assert first_in.wait(5)
        with collector_paused():  # nested in one thread too
            assert not gc.isenabled()
        assert not gc.isenabled()
    assert not gc.isenabled()  # the other thread's block still runs
    second_out.set()
    thread.join(5)
    assert seen == [False, True]
    assert gc.isenabled()


def test_a_collector_that_was_off_stays_off():
    gc.disable()
    try:
        with collector_paused():
            assert not gc.isenabled()
        assert not gc.isenabled()
    finally:
        gc.enable()
