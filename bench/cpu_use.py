"""Where a machine's CPUs go during a benchmark's phase: the CPU time of every process this
one started (and theirs), from Linux's ``/proc`` (``proc(5)``: ``utime`` and ``stime`` of
``/proc/<pid>/stat``, in clock ticks).

Used by ``bench.fusion_latency_bench``: on a shared machine a pipeline's latency depends on
what else runs on its CPUs, and this says how busy they were and with what. Elsewhere than
Linux it measures nothing and says so (:data:`UNAVAILABLE`).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping

UNAVAILABLE = "no /proc here: CPU use is measured on Linux only"

_TICKS_PER_S = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def _stat(pid: int) -> tuple[int, int] | None:
    """``(parent pid, CPU ticks)`` of process ``pid``, None if it is gone."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as file:
            text = file.read()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2 :].split()  # the command (field 2) may hold spaces
    return int(fields[1]), int(fields[11]) + int(fields[12])


def descendants_cpu(root: int) -> dict[int, int]:
    """CPU ticks used so far by ``root`` and every process below it, by pid."""
    stats = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit() and (stat := _stat(int(entry))) is not None:
            stats[int(entry)] = stat
    children: dict[int, list[int]] = {}
    for pid, (parent, _) in stats.items():
        children.setdefault(parent, []).append(pid)
    found, todo = {}, [root]
    while todo:
        pid = todo.pop()
        if pid in stats:
            found[pid] = stats[pid][1]
            todo.extend(children.get(pid, ()))
    return found


class CpuUse:
    """The CPU used by this process's tree between :meth:`start` and :meth:`stop`, in percent
    of one CPU, by process (processes of one name added up)."""

    def __init__(self) -> None:
        self._before: dict[int, int] = {}
        self._started = 0.0

    def start(self, now: float) -> None:
        if os.path.isdir("/proc"):
            self._before, self._started = descendants_cpu(os.getpid()), now

    def stop(self, now: float, name: Callable[[int], str]) -> dict[str, float] | str:
        """``{"total": ..., <name(pid)>: ...}`` in percent of one CPU, largest first; or
        :data:`UNAVAILABLE`."""
        if not os.path.isdir("/proc"):
            return UNAVAILABLE
        seconds = now - self._started
        used: dict[str, float] = {}
        for pid, ticks in descendants_cpu(os.getpid()).items():
            spent = (ticks - self._before.get(pid, 0)) / _TICKS_PER_S
            if spent > 0:
                label = name(pid)
                used[label] = used.get(label, 0.0) + 100.0 * spent / seconds
        ranked = sorted(used.items(), key=lambda item: -item[1])
        return {"total": round(sum(used.values()), 1)} | {
            label: round(percent, 1) for label, percent in ranked
        }


def module_of(pid: int) -> str:
    """The module a Python process runs (``python -m <module>``), else ``other``."""
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as file:
            arguments = file.read().split(b"\0")
    except OSError:
        return "other"
    if b"-m" in arguments[:-1]:
        return arguments[arguments.index(b"-m") + 1].decode(errors="replace")
    return "other"


def namer(roles: Mapping[int, str], workers: Mapping[int, str]) -> Callable[[int], str]:
    """Names a pid: ``bench`` (this process), its role (a child this process started), the
    component a worker process runs, else the module it runs (an idle pool member is
    ``ubitrack_agent.services.worker``, the host manager ``ubitrack_agent.services.host``)."""
    own = os.getpid()

    def name(pid: int) -> str:
        if pid == own:
            return "bench"
        return roles.get(pid) or workers.get(pid) or module_of(pid)

    return name
