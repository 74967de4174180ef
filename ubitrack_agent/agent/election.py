"""Which agent of a domain is the active one: every other agent is a standby (issue 11, item 5).

Every agent process holds a liveliness token ``<root>/agents/<id>`` for as long as it lives;
the active one adds ``<root>/agents/<id>/active`` (``docs/protocol.md``). Ids order the agents:
:func:`new_agent_id` starts with the start time, so the agent started first comes first. The
rule, applied by each agent to the tokens it sees (this module is pure; the runtime feeds it):

* an agent decides nothing until start-up has settled (the tokens of agents already running
  arrive as the links come up);
* a standby becomes active when no agent has been active for ``TAKEOVER_STEP_S`` times its
  place among the standbys alive: when the active agent's tokens disappear the standby started
  first takes over at once, and of two agents starting together only one becomes active; the
  next standby takes over only if the first has not within a step (it may hang, or be a
  stale token);
* an active agent stays active, even if an agent that comes earlier joins later (a clock set
  back, a restarted process): a running system is never handed over needlessly;
* an active agent steps down to standby when it sees another active agent that comes before
  it (two parts of a split network joined again), so two active agents never last.

Neither taking over nor stepping down stops a worker: the active agent adopts the workers that
run (``runtime``), whoever started them.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

TAKEOVER_STEP_S = 1.0
"""How much longer each standby waits than the one before it to take over a vacant domain."""


def new_agent_id() -> str:
    """A fresh agent id: start time (ns, fixed-width hex, so ids sort by it) and pid."""
    return f"{time.time_ns():016x}.{os.getpid()}"


@dataclass
class Election:
    """The agents seen on the domain and whether ``own`` should be active."""

    own: str
    members: set[str] = field(default_factory=set)
    """Agents whose token is up, ``own`` included."""
    actives: set[str] = field(default_factory=set)
    """Agents whose active token is up (``own`` only once it is active)."""
    vacant_since: float | None = None
    """When the agent last saw no other agent active (``None`` while one is)."""

    def __post_init__(self) -> None:
        self.members.add(self.own)

    def member(self, agent: str, appeared: bool) -> None:
        """An agent's token appeared or disappeared (its active token goes with it)."""
        if appeared:
            self.members.add(agent)
        elif agent != self.own:
            self.members.discard(agent)
            self.actives.discard(agent)

    def active(self, agent: str, appeared: bool) -> None:
        """An agent's active token appeared or disappeared."""
        if appeared:
            self.actives.add(agent)
            self.members.add(agent)
        else:
            self.actives.discard(agent)

    def should_be_active(self, active: bool, settled: bool, now: float) -> bool:
        """Whether ``own`` should be active at ``now`` (monotonic seconds), being ``active``
        now, with start-up ``settled`` (module docstring). Called often: it also notes when
        the domain became vacant."""
        others = self.actives - {self.own}
        if others:
            self.vacant_since = None
            return active and not any(other < self.own for other in others)
        if self.vacant_since is None:
            self.vacant_since = now
        if active:
            return True
        place = sorted((self.members - self.actives) | {self.own}).index(self.own)
        return settled and now - self.vacant_since >= place * TAKEOVER_STEP_S

    @property
    def standbys(self) -> list[str]:
        """The agents alive that are not active, in the order they would take over."""
        return sorted(self.members - self.actives)
