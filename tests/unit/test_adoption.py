"""What a host manager reads in ``/proc`` to adopt an orphaned container
(``services/adoption.py``), on this test's own process: a command line's flags, whether a
process is an orphaned worker of a host, and an adopted process's life; and what it accepts
of the orphan's status."""

from __future__ import annotations

import json
import os
import subprocess
from types import SimpleNamespace

import pytest

from tests.unit.test_agent_hosts import KEYS, spec
from ubitrack_agent.net.spec import SpecError
from ubitrack_agent.services import adoption
from ubitrack_agent.services.adoption import (
    UNKNOWN_EXIT,
    AdoptedProcess,
    LocalWorker,
    ask_orphan,
    orphan_worker,
)


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


def reply(status: object) -> SimpleNamespace:
    data = status if isinstance(status, bytes) else json.dumps(status).encode()
    return SimpleNamespace(ok=SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: data)))


def test_an_orphan_is_asked_for_its_components_and_only_its_own_answer_counts():
    worker = LocalWorker("old-pool", 77)
    mine = {"incarnation": "42.ab", "components": {"a": {"spec": spec("a").as_dict()}}}
    other = {"incarnation": "43.cd", "components": {"b": {"spec": spec("b").as_dict()}}}
    session = SimpleNamespace(get=lambda key, timeout: [reply(other), reply(mine)])
    orphan = ask_orphan(session, KEYS, "lab-0", "42.ab", worker)
    assert (orphan.name, orphan.pid, orphan.specs) == ("lab-0", 42, (spec("a"),))

    hostile = [
        b"{not json",
        {"incarnation": "42.ab", "components": []},
        {
            "incarnation": "42.ab",
            "components": {"a": {"spec": {**spec("a").as_dict(), "service": "os.system"}}},
        },
        {"incarnation": "42.ab", "components": {"a": "no spec"}},
    ]
    for status in hostile:
        session = SimpleNamespace(get=lambda key, timeout, status=status: [reply(status)])
        with pytest.raises(SpecError):
            ask_orphan(session, KEYS, "lab-0", "42.ab", worker)
    silent = SimpleNamespace(get=lambda key, timeout: [reply(other)])
    with pytest.raises(SpecError, match="did not answer"):
        ask_orphan(silent, KEYS, "lab-0", "42.ab", worker)
