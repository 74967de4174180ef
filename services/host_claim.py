"""One host manager per name: the first one started serves, a later one waits until it is gone.

Two host managers of one name would both take the agent's requests (a restarted agent that
starts its own while the one its predecessor started, which outlives it, is still importing:
chaos seed 19, ``docs/reliability.md``). So each host manager declares, as its session opens,
the liveliness token ``<root>/host/<name>/claim/<start_ns>.<pid>`` (its start on the wall clock,
and its process id) and keeps it until its session closes; before it serves it waits until no
claim that comes before its own (by start, then pid) is up. The claims are watched with
history, declared as the session opens, so the earlier claims are in by the time the caller
has done its imports (about a second); two host managers started within the time their links
take to come up could still both serve.

A claim key that does not parse is ignored, logged (rate-limited) and counted in
:attr:`HostClaim.counters` (``rejected_claim_keys``; the host manager shows them in its
status). A process that declares a claim with an early start holds every host manager of that
name back, as one declaring the host's token holds the agent's requests: zenoh's
access control (``docs/security.md``) says who may declare either.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections import Counter
from typing import Any

from ubitrack_agent.net import logs
from ubitrack_agent.net.keys import KeySpace

log = logging.getLogger("ubitrack.host")

PUT = "SampleKind.PUT"


class HostClaim:
    """This process's claim to serve host ``name`` (see the module docstring). O(claims) per
    claim event; in practice one or two claims."""

    def __init__(self, session: Any, keys: KeySpace, name: str) -> None:
        self.name = name
        self._prefix = f"{keys.host(name)}/claim/"
        self.own = (time.time_ns(), os.getpid())
        self._earlier: set[tuple[int, int]] = set()
        self._changed = threading.Condition()
        self.counters: Counter[str] = Counter()
        liveliness = session.liveliness()
        self._token = liveliness.declare_token(f"{self._prefix}{self.own[0]}.{self.own[1]}")
        self._watch = liveliness.declare_subscriber(
            f"{self._prefix}*",
            logs.guarded(self._on_claim, self.counters, log, "host claim"),
            history=True,
        )

    def _on_claim(self, sample: Any) -> None:
        """A claim appeared or vanished (on zenoh's thread)."""
        key = str(sample.key_expr)
        claim = parse_claim(key, self._prefix)
        if claim is None:
            logs.count_problem(
                self.counters, "rejected_claim_keys", log, "ignored host claim key %r", key[:200]
            )
            return
        if claim >= self.own:
            return  # ours, or a later one: it waits for us
        with self._changed:
            if str(sample.kind) == PUT:
                self._earlier.add(claim)
            else:
                self._earlier.discard(claim)
                self._changed.notify_all()

    def wait_until_first(self) -> None:
        """Return once no earlier claim of the name is up (this process may serve)."""
        with self._changed:
            if self._earlier:
                waiting = f"host {self.name}: another host manager serves this name: waiting"
                print(waiting, flush=True)
            self._changed.wait_for(lambda: not self._earlier)
        self._watch.undeclare()


def parse_claim(key: str, prefix: str) -> tuple[int, int] | None:
    """(start_ns, pid) of claim key ``key`` under ``prefix``, or None if it is not one."""
    start, dot, pid = key.removeprefix(prefix).partition(".")
    if not key.startswith(prefix) or not dot or not (start.isdigit() and pid.isdigit()):
        return None
    if len(start) > 20 or len(pid) > 10:
        return None
    return int(start), int(pid)
