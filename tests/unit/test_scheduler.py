"""The container's scheduler (``ubitrack_agent.services.scheduler``): one thread running every
component's turns at their deadlines and the calls handed to it, a fault in one counted while the
others go on; and a container whose components need no thread of their own."""

from __future__ import annotations

import threading
import time
from collections import Counter

from tests.unit.test_container import MatchingSession, concatenation
from tests.unit.test_worker_inputs import KEYS
from ubitrack_agent.services.container import Container
from ubitrack_agent.services.scheduler import Scheduler


def settle(scheduler: Scheduler) -> None:
    """Return once everything handed to ``scheduler`` before has run (its queue is FIFO)."""
    done = threading.Event()
    scheduler.call(done.set)
    assert done.wait(5)


class Component:
    """A turn that records when it ran and asks to run again after ``every_s`` (or never)."""

    def __init__(self, every_s: float | None, fail: bool = False) -> None:
        self.every_s, self.fail = every_s, fail
        self.runs: list[float] = []

    def turn(self) -> float | None:
        self.runs.append(time.monotonic())
        if self.fail:
            raise RuntimeError("a bug in a component")
        return None if self.every_s is None else time.monotonic() + self.every_s


def test_turns_run_when_woken_and_again_at_the_deadline_they_return():
    scheduler = Scheduler("s", Counter())
    try:
        ticking, once = Component(0.02), Component(None)
        scheduler.wake(ticking, ticking.turn)
        scheduler.wake(once, once.turn)
        time.sleep(0.2)
        assert len(once.runs) == 1
        assert 5 <= len(ticking.runs) <= 12  # every 20 ms, from its own deadlines
        gaps = [b - a for a, b in zip(ticking.runs, ticking.runs[1:], strict=False)]
        assert min(gaps) >= 0.019
        scheduler.forget(ticking)
        settle(scheduler)
        runs = len(ticking.runs)
        time.sleep(0.1)
        assert len(ticking.runs) == runs  # forgotten: no turn at its deadline
    finally:
        scheduler.stop()
        scheduler.join(5)
    assert not scheduler.thread.is_alive()


def test_a_wake_before_the_deadline_runs_the_turn_at_once_and_keeps_one_deadline():
    scheduler = Scheduler("s", Counter())
    try:
        slow = Component(10.0)
        scheduler.wake(slow, slow.turn)
        settle(scheduler)
        scheduler.wake(slow, slow.turn)
        settle(scheduler)
        assert len(slow.runs) == 2  # woken: at once, not at its deadline in 10 s
    finally:
        scheduler.stop()
        scheduler.join(5)


def test_calls_run_in_order_now_or_later_and_a_fault_is_counted_while_the_others_go_on():
    counters: Counter[str] = Counter()
    scheduler = Scheduler("s", counters)
    try:
        order: list[str] = []
        faulty = Component(0.01, fail=True)
        scheduler.wake(faulty, faulty.turn)
        scheduler.later(0.05, lambda: order.append("later"))
        scheduler.call(lambda: order.append("first"))
        scheduler.call(lambda: 1 / 0)
        scheduler.call(lambda: order.append("second"))
        settle(scheduler)
        assert order == ["first", "second"]
        time.sleep(0.1)
        assert order == ["first", "second", "later"]
        assert counters["internal_errors"] == 2  # the call and the turn, each once
        assert len(faulty.runs) == 1  # a turn that raised has no next deadline
    finally:
        scheduler.stop()
        scheduler.join(5)


def test_components_added_to_a_container_start_no_thread_of_their_own():
    """Ten concatenations in a chain, each with a static input, the first reading a dynamic
    input over zenoh: the dynamic input's thread is the only one the components add (and the
    publishers' of ``net.transport``); commands, status, static inputs and held triggers are
    the scheduler's."""
    session = MatchingSession()
    container = Container(session, KEYS, "c0")
    try:
        specs = [concatenation("c0-0", "CAL/0", "ART/HT")]
        specs += [concatenation(f"c0-{i}", f"CAL/{i}", f"c0-{i - 1}/AC") for i in range(1, 10)]
        before = set(threading.enumerate())  # other tests' threads may still be ending
        container.add(tuple(specs))
        time.sleep(0.2)
        added = [thread.name for thread in set(threading.enumerate()) - before]
        assert added == [f"input {KEYS.data('ART/HT')}"]
        assert len(container.components) == 10
    finally:
        container.stop()
        container.remove(list(container.components))
        container.scheduler.stop()
