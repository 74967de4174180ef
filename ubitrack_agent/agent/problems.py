"""What the agent refused or failed at: counted, logged rate-limited, the last reason kept.

Every rejection of network input (a malformed key, fragment or host report) and every failure
of one of the agent's handlers (run through a :class:`Guard`) goes through
:meth:`Problems.report` under a named counter
(``rejected_worker_keys``, ``rejected_announcements``, ``failed_handlers``, ...): the count and
the last reason of each appear in the agent's status (``ubitrack status``, ``--json``), and the
log gets the first ten of each counter, then every thousandth (``net.logs.rate_limited``), so
a flood of hostile input can neither flood the log nor go unnoticed.
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Callable
from typing import Any, TypeVar

from ubitrack_agent.net import logs

log = logging.getLogger("ubitrack.agent")

MAX_REASON_CHARS = 300
"""Longest reason kept per counter (it may quote network text)."""


class Problems:
    """Counters of refused input and failed handlers, with the last reason of each."""

    def __init__(self, counters: Counter[str] | None = None) -> None:
        self.counters: Counter[str] = Counter() if counters is None else counters
        self.last: dict[str, str] = {}

    def report(
        self,
        counter: str,
        message: str,
        *arguments: Any,
        level: int = logging.WARNING,
        exc_info: BaseException | None = None,
    ) -> None:
        """Count one occurrence under ``counter``, keep its reason (``message % arguments``)
        and log it if :func:`~ubitrack_agent.net.logs.rate_limited` lets it through."""
        self.counters[counter] += 1
        text = (message % arguments)[:MAX_REASON_CHARS]
        self.last[counter] = text
        if logs.rate_limited(self.counters[counter]):
            log.log(level, "%s (%s: %d)", text, counter, self.counters[counter], exc_info=exc_info)


BACKOFF_S = 0.5
"""After a periodic handler failed, it is skipped this long, doubling with each failure in a
row up to :data:`BACKOFF_MAX_S`: a handler failing on the same state again does not spin."""
BACKOFF_MAX_S = 30.0

T = TypeVar("T")


class Guard:
    """Runs the agent's handlers so that none can end the agent: an exception is reported
    (counter ``failed_<name>``, logged rate-limited with its traceback) and the handler's
    ``default`` stands for its result."""

    def __init__(self, problems: Problems) -> None:
        self._problems = problems
        self._streak: dict[str, int] = {}
        self._resume: dict[str, float] = {}

    def call(self, name: str, handler: Callable[..., T], *arguments: Any, default: T) -> T:
        """``handler(*arguments)``, or ``default`` if it raised (handlers of one input: the
        input is consumed either way)."""
        try:
            return handler(*arguments)
        except Exception as exc:
            self._failed(name, exc)
            return default

    def periodic(self, name: str, handler: Callable[[], T], default: T) -> T:
        """``handler()`` for a handler run on every pass of the loop; after a failure it is
        skipped (``default``) for :data:`BACKOFF_S`, doubling while it keeps failing."""
        if time.monotonic() < self._resume.get(name, 0.0):
            return default
        try:
            result = handler()
        except Exception as exc:
            streak = self._streak[name] = self._streak.get(name, 0) + 1
            pause = min(BACKOFF_MAX_S, BACKOFF_S * 2 ** min(streak - 1, 16))
            self._resume[name] = time.monotonic() + pause
            self._failed(name, exc)
            return default
        self._streak.pop(name, None)
        return result

    def _failed(self, name: str, exc: Exception) -> None:
        self._problems.report(
            f"failed_{name}",
            "handler %s failed: %s: %s",
            name,
            type(exc).__name__,
            exc,
            level=logging.ERROR,
            exc_info=exc,
        )
