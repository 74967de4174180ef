"""Spare derivations: the flow a relation falls back on when a sensor of its chosen derivation
is lost, running beside it before the loss (issue [seamless], "make before break").

When a sensor of a relation's derivation stops, the derivation goes on with what it still
has (a fusion on the inputs left, ``agent.standby``) until the agent has planned and started
the derivation that is best without the sensor. If that one reads only sensors the lost
derivation read too, the derivation on standby computes from the same data meanwhile and
nothing better is to be had. If it reads a sensor the chosen derivation left out (a third
tracker, not worth its cost while the better one runs: ``docs/planner.md``, "Cost model"),
the application gets the worse estimate for as long as the agent takes to notice the loss
(the provider's token, or the edge going quiet: ``agent.liveness``), plan, start the
components and let them converge: a few hundred milliseconds of the camera alone where a
tracker was available. That derivation is started beforehand as a *spare*: its producer
puts on the relation's key too, and the hand-over keeps it back while the chosen derivation
is more certain (``services.handover``, rule 2); when the chosen one loses the sensor its
estimate becomes less certain than the spare's and the spare takes the key at its next
sample. The agent then plans the spare's derivation as the relation's own (the same
component ids: ``graph.dataflow.from_solution``) and finds it running.

The spare of each sensor is the cheapest of the planner's alternatives (best first, at most
``per_relation`` of them) that does not read it. The list is bounded, so in a room with many
trackers the best derivation without a sensor may not be in it: the spare is then the best
listed one, or none. Cost: O(sensors x alternatives x measured edges) per relation planned,
no planner call; running them costs their components' CPU, O(sensors of the derivation)
derivations per relation at most, and none where the derivation reads every sensor that an
alternative does (the demo's camera and tracker fused).

**Replicas** (:class:`Redundancy`, ``ubitrack agent --replicas N``) stand in for the loss of
the process instead: N copies of the chosen derivation under other component ids
(``graph.dataflow.from_solution``, ``replica``), listed with the spares. The grouping keeps
each copy in another container (``agent.placement.group_containers``, rule 5); when the
process running the producer that holds the key dies, its token leaves and a copy puts its
next sample (``services.handover``, rule 5), its filters warm. Cost: N times the derivation's
components and CPU; planning, N more data flows, O(steps x inputs) each.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # (the command line reads this module's settings without the planner)
    from ubitrack_agent.graph.planner import Solution

MAX_REPLICAS = 3
"""The most replicas of a derivation the agent runs (each costs the derivation's CPU again)."""


@dataclass(frozen=True)
class Redundancy:
    """What the agent runs beside each relation's chosen derivation (module docstring):
    ``spares`` for the loss of a sensor, and ``replicas`` copies of the derivation for the loss
    of the process running it (0 to :data:`MAX_REPLICAS`)."""

    spares: bool = True
    replicas: int = 0

    def __post_init__(self) -> None:
        if not 0 <= self.replicas <= MAX_REPLICAS:
            raise ValueError(f"replicas: expected 0 to {MAX_REPLICAS}, got {self.replicas}")


DEFAULT_REDUNDANCY = Redundancy()
"""Spares, no replicas: the agent's default (``ubitrack agent --no-spares``, ``--replicas``)."""


def sensors(solution: Solution) -> frozenset[str]:
    """The providers of the dynamic measured edges ``solution`` reads (the sensors it stops
    without; a static edge's provider, a database, is read once)."""
    return frozenset(
        record.provider
        for record in solution.records.values()
        if record.measured and not record.static
    )


def spare_solutions(chosen: Solution, solutions: Sequence[Solution]) -> list[Solution]:
    """The spares of ``chosen`` among ``solutions`` (the planner's alternatives, best first),
    in the order of the sensors they stand in for: for each sensor ``chosen`` reads, the first
    alternative that does not read it, if that one reads a sensor ``chosen`` does not (module
    docstring); each spare once."""
    used = sensors(chosen)
    by_solution = [(solution, sensors(solution)) for solution in solutions]
    spares: list[Solution] = []
    for sensor in sorted(used):
        found = next(((s, read) for s, read in by_solution if sensor not in read), None)
        if found is None or any(found[0] is s for s in (chosen, *spares)):
            continue
        if not found[1] <= used:
            spares.append(found[0])
    return spares
