"""Termination handlers (:mod:`ubitrack_agent.net.lifecycle`): a signal arriving while the
main thread holds a lock the handler needs must not deadlock the process."""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator

import pytest

from ubitrack_agent.net.lifecycle import on_termination


@pytest.fixture
def restored_signals() -> Iterator[None]:
    saved = {number: signal.getsignal(number) for number in (signal.SIGTERM, signal.SIGINT)}
    yield
    on_termination(lambda: None)
    for number, handler in saved.items():
        signal.signal(number, handler)


def test_a_signal_while_the_main_thread_holds_the_handlers_lock_is_handled_after(
    restored_signals,
):
    lock, handled = threading.Lock(), threading.Event()

    def handler() -> None:  # as Event.set does: takes a lock the main thread may hold
        if lock.acquire(timeout=2.0):
            handled.set()
            lock.release()

    on_termination(handler)
    with lock:
        signal.raise_signal(signal.SIGTERM)
        sum(range(10_000))  # the Python-level signal handler runs here, on the main thread
        assert not handled.is_set()
    assert handled.wait(5.0)


def test_the_last_handler_registered_runs_and_a_failing_one_does_not_stop_the_next(
    restored_signals,
):
    calls: list[str] = []
    done = threading.Event()

    def failing() -> None:
        calls.append("failing")
        done.set()
        raise RuntimeError("handler failed")

    on_termination(lambda: calls.append("replaced"))
    on_termination(failing)
    signal.raise_signal(signal.SIGINT)
    assert done.wait(5.0)
    done.clear()
    on_termination(lambda: (calls.append("second"), done.set()))
    signal.raise_signal(signal.SIGTERM)
    assert done.wait(5.0)
    assert calls == ["failing", "second"]
