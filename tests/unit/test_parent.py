"""A worker process's host manager gone (``services/parent.py``): the process exits if it is
still starting, keeps running if its token is up, and leaves the pool if idle. The host
manager's pipe is a local ``os.pipe``; exiting is recorded instead of done."""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator

import pytest

from ubitrack_agent.services.parent import Parent

WAIT_S = 5.0
"""Longest wait for the watching thread (it reacts within milliseconds)."""


class Host:
    """The write end of the pipe a :class:`Parent` watches; :meth:`die` closes it."""

    def __init__(self) -> None:
        self.read_end, self._write_end = os.pipe()
        self.exited: list[int] = []
        self.ended = threading.Event()
        """Set once the parent has exited or woken the pool."""
        self.woken = False
        self.parent = Parent(self.read_end, exit_process=self._exit)
        self.parent.when_gone(self._wake)

    def _exit(self, status: int) -> None:
        self.exited.append(status)
        self.ended.set()

    def _wake(self) -> None:
        self.woken = True
        self.ended.set()

    def die(self) -> None:
        os.write(self._write_end, b"anything the host manager might write is ignored")
        os.close(self._write_end)
        assert self.ended.wait(WAIT_S)


@pytest.fixture
def host() -> Iterator[Host]:
    host = Host()
    yield host
    os.close(host.read_end)


def test_a_process_still_starting_exits(host):
    host.die()
    assert host.exited == [0] and not host.woken


def test_a_serving_process_keeps_running_and_ends_when_released(host):
    assert host.parent.serve(lambda: "token") == "token"
    host.die()
    assert host.exited == [] and host.woken
    assert not host.parent.idle()  # released: it does not go back to the pool


def test_an_idle_process_leaves_the_pool_and_starts_nothing(host):
    assert host.parent.idle()
    host.die()
    assert host.exited == [] and host.woken
    assert not host.parent.start()


def test_a_process_starting_again_from_the_pool_exits(host):
    host.parent.serve(lambda: "token")
    assert host.parent.idle()
    assert host.parent.start()
    host.die()
    assert host.exited == [0] and not host.woken
