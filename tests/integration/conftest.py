"""Helpers for integration tests: free loopback ports, processes that never outlive a test, and
(``netns``) machines in network namespaces."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
from collections.abc import Iterator

import pytest

from tests.integration.netns import netns  # noqa: F401  (a fixture: machines in namespaces)


@pytest.fixture
def processes() -> Iterator[list[subprocess.Popen]]:
    """Processes a test starts; each is started in its own group and killed with it at the end."""
    started: list[subprocess.Popen] = []
    yield started
    end_groups(started)


def end_groups(started: list[subprocess.Popen]) -> None:
    """End the process group of each of ``started`` still running: SIGTERM, SIGKILL after 5 s."""
    for process in started:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGTERM)
            try:
                process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()


def kill_tagged(tag: str) -> list[str]:
    """Kill every process whose command line contains ``tag`` (a test's unique domain), such
    as workers orphaned on purpose when a test kills the agent; return what was found."""
    found = subprocess.run(["pgrep", "-f", tag], capture_output=True, text=True).stdout.split()
    own = str(os.getpid())
    for pid in found:
        if pid != own:
            with contextlib.suppress(ProcessLookupError):
                os.kill(int(pid), signal.SIGKILL)
    return [pid for pid in found if pid != own]
