"""Containers a host manager that died left running, adopted by the next host manager of its name.

A container outlives its host manager once it serves (:mod:`ubitrack_agent.services.parent`), so
the applications keep their data; but then nobody restores it if it dies too. The next host
manager of the same name (the agent starts one again, or an operator) adopts such orphans: it
finds them from their container tokens (``<root>/container/<name>/<pid>.<nonce>``), and takes
one only if the process is on this machine and is one of its name's: ``/proc/<pid>/cmdline``
runs ``ubitrack_agent.services.worker`` with ``--host-name`` its name and ``--prefix`` and
``--domain`` its key space (how :mod:`ubitrack_agent.services.supervisor` starts every worker
process), and its parent is no host manager (one that runs owns it). What the container runs
it asks the container itself (its status names each component's current specification,
``ubitrack_agent.services.container``). From then on the adopted container is its host
manager's as if it had started it: its components are in the host manager's status (the agent
places them there), stopped and removed through it, and restored if the process dies.

The process is not the host manager's child, so it is watched in ``/proc``: alive while
``/proc/<pid>/stat`` shows it running (not a zombie) with the start time it had when adopted (a
pid used again is another process); its exit status is unknown. This is the adoption of orphaned
children by a subreaper (Linux ``PR_SET_CHILD_SUBREAPER``), done by name instead of by the
kernel, since the new host manager is no ancestor of the orphans.

Linux only (``/proc``); elsewhere nothing is adopted.
"""

from __future__ import annotations

import itertools
import os
import signal
import subprocess
import time
from dataclasses import dataclass
from typing import Any

from ubitrack_agent.net.json_messages import MessageError, load_object
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.spec import ComponentSpec, SpecError, parse_components
from ubitrack_agent.services.spec import check_spec

WORKER_MODULE = "ubitrack_agent.services.worker"
HOST_MODULE = "ubitrack_agent.services.host"
UNKNOWN_EXIT = -256
"""What :meth:`AdoptedProcess.poll` returns once the process has ended: its exit status is
its parent's to know (no signal number or exit status is -256); reported as unknown."""
WAIT_STEP_S = 0.02
ASK_TIMEOUT_S = 2.0
"""Longest wait for an orphan container's status."""
MAX_STATUS_BYTES = 4 * 1024 * 1024
"""Largest container status read (a thousand components' specifications)."""


@dataclass(frozen=True)
class LocalWorker:
    """A worker process of this machine, from ``/proc``: its pool id and its start time
    (clock ticks since boot, which tell it from a later process given the same pid)."""

    pool_id: str
    started: int


@dataclass(frozen=True)
class Orphan:
    """A container left running by a host manager that died: its name, its process's
    incarnation (``<pid>.<nonce>``) and what ``/proc`` says of it, and its components'
    current specifications."""

    name: str
    incarnation: str
    worker: LocalWorker
    specs: tuple[ComponentSpec, ...]

    @property
    def pid(self) -> int:
        return int(self.incarnation.partition(".")[0])


def orphan_worker(pid: int, host: str, prefix: str, domain: str) -> LocalWorker | None:
    """The worker process ``pid`` if it runs on this machine for host ``host`` in key space
    ``<prefix>/<domain>`` and no host manager is its parent; else None (module docstring).
    O(its command line)."""
    argv = _command_line(pid)
    flags = _flags(argv)
    wanted = {"-m": WORKER_MODULE, "--host-name": host, "--prefix": prefix, "--domain": domain}
    if any(flags.get(flag) != value for flag, value in wanted.items()) or "--pool-id" not in flags:
        return None
    stat = _stat(pid)
    if stat is None or stat[0] == "Z" or _is_host_manager(_command_line(stat[1])):
        return None
    return LocalWorker(flags["--pool-id"], stat[2])


def _is_host_manager(argv: list[str]) -> bool:
    """Whether command line ``argv`` runs a host manager (``python -m
    ubitrack_agent.services.host``, or ``ubitrack host``)."""
    cli = any(arg.endswith("ubitrack") or arg == "ubitrack_agent.cli" for arg in argv)
    return HOST_MODULE in argv or (cli and "host" in argv)


def ask_orphan(
    session: Any, keys: KeySpace, name: str, incarnation: str, worker: LocalWorker
) -> Orphan:
    """Container ``name``'s components, asked of its process ``incarnation`` (its status on
    ``<root>/status/<name>``), each specification checked as a start's
    (``ubitrack_agent.services.spec.check_spec``: registered services only); blocks up to
    ``ASK_TIMEOUT_S``. :class:`SpecError` if it does not answer or its answer is malformed.
    O(its components)."""
    for reply in session.get(keys.status(name), timeout=ASK_TIMEOUT_S):
        if reply.ok is None:
            continue
        try:
            status = load_object(reply.ok.payload.to_bytes(), MAX_STATUS_BYTES)
        except MessageError as exc:
            raise SpecError(f"container {name}: status: {exc.reason}") from None
        if status.get("incarnation") != incarnation:
            continue  # another process of that name
        components = status.get("components")
        if not isinstance(components, dict):
            raise SpecError(f"container {name}: status: no components")
        raw = [
            entry.get("spec") if isinstance(entry, dict) else None for entry in components.values()
        ]
        specs = parse_components(raw, f"container {name}")
        for spec in specs:
            check_spec(spec)
        return Orphan(name, incarnation, worker, specs)
    raise SpecError(f"container {name}: process {incarnation} did not answer")


class AdoptedProcess:
    """An adopted container's process, watched in ``/proc`` (module docstring): what the
    supervisor uses of a :class:`subprocess.Popen` (``pid``, ``poll``, ``terminate``,
    ``kill``, ``wait``)."""

    def __init__(self, pid: int, started: int) -> None:
        self.pid = pid
        self.started = started
        self.returncode: int | None = None

    def poll(self) -> int | None:
        """None while the process runs, else :data:`UNKNOWN_EXIT`."""
        if self.returncode is None:
            stat = _stat(self.pid)
            if stat is None or stat[0] == "Z" or stat[2] != self.started:
                self.returncode = UNKNOWN_EXIT
        return self.returncode

    def terminate(self) -> None:
        self._signal(signal.SIGTERM)

    def kill(self) -> None:
        self._signal(signal.SIGKILL)

    def _signal(self, number: int) -> None:
        if self.poll() is None:
            try:
                os.kill(self.pid, number)
            except ProcessLookupError:
                self.returncode = UNKNOWN_EXIT

    def wait(self, timeout: float | None = None) -> int:
        """:data:`UNKNOWN_EXIT` once the process has ended; :class:`subprocess.TimeoutExpired`
        after ``timeout`` seconds."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while self.poll() is None:
            if deadline is not None and time.monotonic() > deadline:
                raise subprocess.TimeoutExpired(f"adopted process {self.pid}", timeout or 0.0)
            time.sleep(WAIT_STEP_S)
        return UNKNOWN_EXIT


def _command_line(pid: int) -> list[str]:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as file:
            return file.read().decode(errors="replace").split("\0")
    except OSError:
        return []


def _flags(argv: list[str]) -> dict[str, str]:
    """Each flag of a command line with the argument after it (the first occurrence)."""
    flags: dict[str, str] = {}
    for flag, value in itertools.pairwise(argv):
        if flag.startswith("-"):
            flags.setdefault(flag, value)
    return flags


def _stat(pid: int) -> tuple[str, int, int] | None:
    """State, parent pid and start time (clock ticks after boot) of process ``pid``, from
    ``/proc/<pid>/stat`` (proc(5)); None if there is none."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as file:
            fields = file.read().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    try:
        return fields[0], int(fields[1]), int(fields[19])
    except (IndexError, ValueError):
        return None
