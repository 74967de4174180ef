"""``net.thread_pool.ThreadPool``: a thread only when none is idle, never more than its bound,
every call run."""

from __future__ import annotations

import threading

from ubitrack_agent.net.thread_pool import ThreadPool


def test_calls_one_after_another_share_one_thread():
    pool = ThreadPool("test-one", 4)
    done = threading.Semaphore(0)
    ran: list[tuple[int, str]] = []

    def call(k: int) -> None:
        ran.append((k, threading.current_thread().name))
        done.release()

    for k in range(20):
        pool.submit(call, k)
        assert done.acquire(timeout=5.0)
    assert [k for k, _ in ran] == list(range(20))
    assert {name for _, name in ran} == {"test-one-1"} and pool.started == 1


def test_busy_threads_grow_the_pool_up_to_its_bound_and_every_call_runs():
    pool = ThreadPool("test-bound", 3)
    release = threading.Event()
    done = threading.Semaphore(0)
    ran: list[int] = []

    def call(k: int) -> None:
        release.wait(timeout=5.0)
        ran.append(k)
        done.release()

    for k in range(10):
        pool.submit(call, k)
    assert pool.started == 3  # the other seven wait for one of the three
    release.set()
    assert all(done.acquire(timeout=5.0) for _ in range(10))
    assert sorted(ran) == list(range(10)) and pool.started == 3
