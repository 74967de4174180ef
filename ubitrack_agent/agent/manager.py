"""The local service manager: starts, stops and reaps worker processes on this host.

Starting a Python worker costs a few hundred milliseconds (interpreter, numpy, scipy, OpenCV),
too slow for reconfiguration. The manager therefore keeps a **warm pool** of idle workers
(``python -m services.worker --pool-id ID``) that have imported everything and wait for a
specification on ``<root>/pool/<ID>``; starting a component hands it to a ready pool worker and
tops the pool up. With no ready pool worker, it starts a fresh process with ``--spec``. A
stopped component's process returns to the pool (``services.worker.Pool``) while the pool is
short, so sensors coming and going reuse processes instead of paying the imports again.

Only registered services are ever started (checked here, and again by the worker); workers are
started without a shell, with the specification as one argument. Idle pool workers exit when
the manager's process dies (their standard input closes); assigned workers outlive an agent
crash on purpose, so the applications keep their data while the agent restarts and adopts them.
"""

from __future__ import annotations

import json
import logging
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Sequence
from typing import Any

from services.registry import lookup
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.spec import ComponentSpec

log = logging.getLogger("ubitrack.manager")

STOP_GRACE_S = 3.0
"""How long a stopped worker may take to exit before it is killed."""
REFILL_QUIET_S = 3.0
"""The pool is topped up only after this long without a component being started."""


class ServiceManager:
    """Supervises the worker processes this agent started on the local host."""

    def __init__(
        self,
        session: Any,
        keys: KeySpace,
        worker_flags: Sequence[str],
        pool_size: int = 8,
        python: str = sys.executable,
    ) -> None:
        self._session = session
        self._keys = keys
        self._flags = list(worker_flags)
        self._python = python
        self._pool_size = pool_size
        self._tag = uuid.uuid4().hex[:6]
        self._pool: dict[str, subprocess.Popen] = {}
        self._ready: set[str] = set()
        self._lock = threading.Lock()
        self.processes: dict[str, subprocess.Popen] = {}
        self._pool_ids: dict[str, str] = {}
        """Instance -> the pool id of the process running it (released back to the pool)."""
        self._stopping: list[tuple[subprocess.Popen, float]] = []
        self._last_start = -REFILL_QUIET_S
        self._watch = session.liveliness().declare_subscriber(
            f"{keys.root}/pool/*", self._on_pool_token, history=True
        )
        self._fill_pool()

    def _on_pool_token(self, sample: Any) -> None:
        pool_id = str(sample.key_expr).rsplit("/", 1)[-1]
        with self._lock:
            if str(sample.kind) == "SampleKind.PUT" and pool_id in self._pool:
                self._ready.add(pool_id)
            else:
                self._ready.discard(pool_id)

    def _new_pool_id(self) -> str:
        return f"{self._tag}-{uuid.uuid4().hex[:8]}"

    def _spawn(self, *arguments: str) -> subprocess.Popen:
        return subprocess.Popen(
            [self._python, "-m", "services.worker", *arguments, *self._flags],
            stdin=subprocess.PIPE,  # closes when this process dies: idle workers then exit
        )

    def _fill_pool(self) -> None:
        """Top the pool up, one process at a time and only once reconfiguration has been quiet
        for ``REFILL_QUIET_S``: a worker importing numpy, scipy and OpenCV keeps a core busy
        for about a second, which would starve a data flow that has just been rewired."""
        with self._lock:
            starting = set(self._pool) - self._ready
        quiet = time.monotonic() - self._last_start > REFILL_QUIET_S
        if len(self._pool) < self._pool_size and quiet and not starting:
            pool_id = self._new_pool_id()
            self._pool[pool_id] = self._spawn("--pool-id", pool_id)

    def _take_ready(self) -> tuple[str, subprocess.Popen] | None:
        with self._lock:
            if not self._ready:
                return None
            pool_id = self._ready.pop()
        return pool_id, self._pool.pop(pool_id)

    def start(self, spec: ComponentSpec) -> None:
        """Run ``spec``: on a ready pool worker if there is one, else in a new process."""
        lookup(spec.service)  # KeyError for anything not registered
        taken = self._take_ready()
        if taken is not None:
            pool_id, process = taken
            self._session.put(self._keys.pool(pool_id), spec.to_json())
            log.info("%s: assigned to pool worker %s", spec.instance, pool_id)
        else:
            pool_id = self._new_pool_id()
            process = self._spawn("--pool-id", pool_id, "--spec", spec.to_json())
            log.info("%s: started process %d", spec.instance, process.pid)
        self.processes[spec.instance] = process
        self._pool_ids[spec.instance] = pool_id
        self._last_start = time.monotonic()

    def stop(self, instance: str) -> None:
        """Ask ``instance`` to stop (it may be a worker of an earlier agent: any host)."""
        self._session.put(self._keys.control(instance), json.dumps({"stop": True}))
        process = self.processes.pop(instance, None)
        pool_id = self._pool_ids.pop(instance, None)
        if process is not None and pool_id is not None and len(self._pool) < self._pool_size:
            self._pool[pool_id] = process  # released: back in the pool once its token is up
        elif process is not None:
            process.terminate()
            self._stopping.append((process, time.monotonic() + STOP_GRACE_S))

    def reap(self) -> list[str]:
        """Collect exited processes; return the instances whose worker died on its own."""
        died = [i for i, p in self.processes.items() if p.poll() is not None]
        for instance in died:
            log.warning("%s: worker exited with %s", instance, self.processes[instance].returncode)
            del self.processes[instance]
            self._pool_ids.pop(instance, None)
        now = time.monotonic()
        still = []
        for process, deadline in self._stopping:
            if process.poll() is None:
                if now > deadline:
                    process.kill()
                still.append((process, deadline))
        self._stopping = still
        for pool_id in [p for p, proc in self._pool.items() if proc.poll() is not None]:
            del self._pool[pool_id]
        self._fill_pool()
        return died

    def shutdown(self) -> None:
        """Stop every process this manager started (the agent is ending cleanly)."""
        self._watch.undeclare()
        everything = [*self.processes.values(), *self._pool.values()]
        everything += [process for process, _ in self._stopping]
        for process in everything:
            if process.poll() is None:
                process.terminate()
        for process in everything:
            try:
                process.wait(timeout=STOP_GRACE_S)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
        self.processes.clear()
        self._pool.clear()
