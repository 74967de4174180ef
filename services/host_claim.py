"""One host manager per name: of those started together, the first claim serves, the others exit.

Two host managers of one name would both take the agent's requests (a restarted agent that
starts its own while the one its predecessor started, which outlives it, is still importing:
chaos seed 19, ``docs/reliability.md``; or an operator starting ``ubitrack host`` twice). So
each host manager declares, as its session opens, the liveliness token
``<root>/host/<name>/claim/<start_ns>.<nonce>.<pid>`` (its start on the wall clock, a random
64-bit number and its process id) and keeps it until its session closes. It watches the claims
of its name, and the host token ``<root>/host/<name>`` of one already serving, both with
history, for ``SETTLE_S`` from its own declaration (the time its links take to come up and the
claims to cross them; the imports of the host manager's services run meanwhile, so the window
costs little). Then it decides, once, by one total order that every claimant applies to what
it has heard:

* a host token is up (one serves already), or a claim up that comes before its own (by start,
  then the random number: no two claims tie): it gives way, printing which one came first,
  and exits with :data:`NAME_TAKEN` (the agent then adopts the one that serves:
  ``ubitrack_agent.commands.agent``);
* else it serves.

Two host managers started at the same instant both hear each other within the window, so
exactly one of them serves (``tests/integration/test_host.py`` starts such pairs); one started
after another's window has closed hears that one's claim or host token, which came before.
This is the tie-break of a bully election without rounds (Garcia-Molina 1982): the order is
fixed when the claims are made, so nobody needs to answer anybody.

A claim key that does not parse is ignored, logged (rate-limited) and counted in
:attr:`HostClaim.counters` (``rejected_claim_keys``; the host manager shows them in its
status). A process that declares a claim with an early start holds every host manager of that
name back, as one declaring the host's token holds the agent's requests: zenoh's
access control (``docs/security.md``) says who may declare either.
"""

from __future__ import annotations

import logging
import os
import secrets
import threading
import time
from collections import Counter
from collections.abc import Iterable
from typing import Any, NamedTuple

from ubitrack_agent.net import logs
from ubitrack_agent.net.keys import KeySpace

log = logging.getLogger("ubitrack.host")

PUT = "SampleKind.PUT"
SETTLE_S = 1.0
"""How long a host manager hears the claims of its name before it decides (its links' time;
about 10 ms on loopback, idle)."""
NAME_TAKEN = 3
"""Exit status of a host manager that gave way to another of its name."""


class Claim(NamedTuple):
    """A host manager's claim to a name; claims are ordered by start, then nonce."""

    start_ns: int
    nonce: int
    pid: int

    def chunk(self) -> str:
        return f"{self.start_ns}.{self.nonce}.{self.pid}"


def first_before(own: Claim, claims: Iterable[Claim], served: bool) -> str | None:
    """Why ``own`` must give way (a host token is up: ``served``; or the first of ``claims``
    comes before it), or None if it serves. O(claims)."""
    if served:
        return "another host manager of this name serves already"
    earlier = min((claim for claim in claims if claim < own), default=None)
    if earlier is None:
        return None
    return f"another host manager of this name (pid {earlier.pid}) started first"


class HostClaim:
    """This process's claim to serve host ``name`` (see the module docstring). O(claims) per
    claim event; in practice one or two claims."""

    def __init__(self, session: Any, keys: KeySpace, name: str, settle_s: float = SETTLE_S) -> None:
        self.name = name
        self._prefix = f"{keys.host(name)}/claim/"
        self._host_key = keys.host(name)
        self.own = Claim(time.time_ns(), secrets.randbits(63), os.getpid())
        self._claims: set[Claim] = set()
        self._served = False
        self._lock = threading.Lock()
        self.counters: Counter[str] = Counter()
        liveliness = session.liveliness()
        self._token = liveliness.declare_token(self._prefix + self.own.chunk())
        self._decide_at = time.monotonic() + settle_s
        self._watches = [
            liveliness.declare_subscriber(
                f"{self._prefix}*",
                logs.guarded(self._on_claim, self.counters, log, "host claim"),
                history=True,
            ),
            liveliness.declare_subscriber(
                keys.host(name),
                logs.guarded(self._on_host, self.counters, log, "host token"),
                history=True,
            ),
        ]

    def _on_claim(self, sample: Any) -> None:
        """A claim appeared or vanished (on zenoh's thread)."""
        key = str(sample.key_expr)
        claim = parse_claim(key, self._prefix)
        if claim is None:
            logs.count_problem(
                self.counters, "rejected_claim_keys", log, "ignored host claim key %r", key[:200]
            )
            return
        with self._lock:
            if str(sample.kind) == PUT:
                self._claims.add(claim)
            else:
                self._claims.discard(claim)

    def _on_host(self, sample: Any) -> None:
        """The host token of one serving appeared or vanished (on zenoh's thread). A token
        declared on a wildcard that matches the host's key (``<root>/host/*``) is no host
        manager's: ignored, counted (``rejected_host_tokens``), so it cannot hold every host
        manager back."""
        key = str(sample.key_expr)
        if key != self._host_key:
            logs.count_problem(
                self.counters, "rejected_host_tokens", log, "ignored host token %r", key[:200]
            )
            return
        with self._lock:
            self._served = str(sample.kind) == PUT

    def settle(self) -> str | None:
        """Once ``SETTLE_S`` has passed since the claim was declared: why this process must
        give way (it should exit with :data:`NAME_TAKEN`), or None if it serves."""
        time.sleep(max(0.0, self._decide_at - time.monotonic()))
        with self._lock:
            rival = first_before(self.own, self._claims, self._served)
        for watch in self._watches:
            watch.undeclare()
        return rival


def parse_claim(key: str, prefix: str) -> Claim | None:
    """The claim of key ``key`` under ``prefix``, or None if it is not one."""
    if not key.startswith(prefix):
        return None
    fields = key.removeprefix(prefix).split(".")
    if len(fields) != 3 or not all(field.isdigit() for field in fields):
        return None
    start, nonce, pid = fields
    if len(start) > 20 or len(nonce) > 20 or len(pid) > 10:
        return None
    return Claim(int(start), int(nonce), int(pid))
