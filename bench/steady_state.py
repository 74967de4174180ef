"""Waiting for a system's steady state before a bench measures it: the host manager's warm pool
full. The pool fills one process at a time after start-up (``docs/performance.md``, "Worker
start-up"), and each cold start imports numpy, scipy and OpenCV on the CPUs the measured flow
runs on, so a phase measured before it is full measures the start-up, not the flow."""

from __future__ import annotations

from typing import Any

from tests.integration.zenoh_helpers import wait_until
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.services.host import DEFAULT_POOL_SIZE


def wait_for_warm_pool(
    session: Any, keys: KeySpace, size: int = DEFAULT_POOL_SIZE, timeout: float = 120.0
) -> None:
    """Return once ``size`` idle pool workers are up (their liveliness tokens); fail
    (``AssertionError``, from ``wait_until``) after ``timeout`` seconds."""
    pool = session.liveliness().declare_subscriber(f"{keys.root}/pool/*", history=True)
    warm: set[str] = set()

    def full() -> bool:
        while (token := pool.try_recv()) is not None:
            (warm.add if str(token.kind).endswith("PUT") else warm.discard)(str(token.key_expr))
        return len(warm) >= size

    try:
        wait_until(full, timeout=timeout)
    finally:
        pool.undeclare()
