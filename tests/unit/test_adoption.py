"""What a host manager reads in ``/proc`` to adopt an orphaned container
(``services/adoption.py``), on this test's own process: a command line's flags, whether a
process is an orphaned worker of a host, and an adopted process's life."""

from __future__ import annotations

import os
import subprocess

import pytest

from ubitrack_agent.services import adoption
from ubitrack_agent.services.adoption import UNKNOWN_EXIT, AdoptedProcess, orphan_worker


def test_flags_are_read_with_the_argument_after_them():
    argv = ["python", "-P", "-m", "ubitrack_agent.services.worker", "--pool-id", "ab-1"]
    argv += ["--host-name", "lab", "--no-multicast"]
    flags = adoption._flags(argv)
    assert flags["-m"] == "ubitrack_agent.services.worker"
    assert (flags["--pool-id"], flags["--host-name"]) == ("ab-1", "lab")
    assert "--no-multicast" not in flags


def test_a_host_manager_is_known_by_its_command_line():
    assert adoption._is_host_manager(["python", "-P", "-m", "ubitrack_agent.services.host"])
    assert adoption._is_host_manager(["/opt/ubitrack/bin/ubitrack", "host", "--name", "lab"])
    assert not adoption._is_host_manager(["/opt/ubitrack/bin/ubitrack", "agent"])
    assert not adoption._is_host_manager(["python", "-m", "ubitrack_agent.services.worker"])


def test_a_process_that_is_no_worker_of_the_host_is_no_orphan():
    assert orphan_worker(os.getpid(), "lab", "ubitrack", "default") is None  # pytest
    assert orphan_worker(2**22 + 12345, "lab", "ubitrack", "default") is None  # no process


def test_an_adopted_process_runs_while_its_pid_has_its_start_time():
    state, _, started = adoption._stat(os.getpid())
    assert state in "RS"
    alive = AdoptedProcess(os.getpid(), started)
    assert alive.poll() is None
    with pytest.raises(subprocess.TimeoutExpired):
        alive.wait(timeout=0.0)
    reused = AdoptedProcess(os.getpid(), started + 1)  # the pid, given to another process
    assert reused.poll() == UNKNOWN_EXIT
    reused.kill()  # signals nothing: it is not the process adopted
    assert reused.wait(timeout=0.0) == UNKNOWN_EXIT
