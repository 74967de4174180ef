"""Ground truth on zenoh: the simulated world answers queries for any relation.

Key ``<root>/truth/<from>/<to>`` (:meth:`ubitrack_agent.net.keys.KeySpace.truth`), optional
parameter ``t=<ns>`` (default: the time of the query's arrival), on real time: the world
moves on the real clock, whatever ``--clock-offset-ms`` says (a simulated host whose clock is
off stamps its measurements on its own clock; corrected to the agent's clock they compare with
the truth, unless the agent runs with an offset too, ``docs/protocol.md``, "Clocks"). The
reply is one encoded measurement (``ubitrack_agent.core.codec``):

* between two frames: :class:`~ubitrack_agent.core.Pose` of ``<to>`` in ``<from>``;
* camera frame to its image plane: the :class:`~ubitrack_agent.core.Projection` ``K [I | 0]``;
* image plane to a frame: the noise-free :class:`~ubitrack_agent.core.Position2D` of the
  frame's origin (with distortion), or an error reply if it is out of view.

Bad parameters get an error reply naming the problem. One queryable per pair of names is
declared (so no wildcard key is built outside :mod:`ubitrack_agent.net.keys`); zenoh callbacks only
queue the queries and one thread answers them.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from typing import Any

from ubitrack_agent.core import Measurement, Pose, Position2D, Projection, encode
from ubitrack_agent.core.measurements import MAX_TIMESTAMP_NS
from ubitrack_agent.net.encodings import MSGPACK
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.sim_trackers.world import World

log = logging.getLogger("ubitrack.sim.world")


class TruthError(ValueError):
    """A truth query cannot be answered (out of view, bad time)."""


def truth(world: World, source: str, target: str, timestamp_ns: int) -> Measurement:
    """The ground truth of ``source -> target`` at ``timestamp_ns`` (see the module docstring)."""
    planes = world.image_planes
    if source in planes:
        seen = world.project(source, [target], timestamp_ns)
        if target not in seen:
            raise TruthError(f"{target} is not in view of {source} at t={timestamp_ns}")
        return Position2D(timestamp_ns, seen[target])
    if target in planes:
        if planes[target].camera != source:
            raise TruthError(
                f"{target} is the image plane of {planes[target].camera}, not {source}"
            )
        return Projection(timestamp_ns, planes[target].projection_matrix())
    return Pose(timestamp_ns, *world.pose(source, target, timestamp_ns))


def _timestamp(parameter: str | None) -> int:
    if parameter is None:
        return time.time_ns()
    try:
        value = int(parameter)
    except ValueError:
        raise TruthError(f"t must be integer nanoseconds, got {parameter!r}") from None
    if not 0 <= value <= MAX_TIMESTAMP_NS:
        raise TruthError(f"t out of range [0, 2**63): {value}")
    return value


class TruthServer:
    """Serves ``world``'s ground truth on ``<root>/truth/<from>/<to>`` until closed."""

    def __init__(self, session: Any, keys: KeySpace, world: World) -> None:
        self.world = world
        self.answered = 0
        self.failed = 0
        self._queries: queue.SimpleQueue[tuple[str, str, Any] | None] = queue.SimpleQueue()
        names = [*world.frames, *world.image_planes]
        self._queryables = [
            session.declare_queryable(
                keys.truth(source, target),
                lambda query, pair=(source, target): self._queries.put((*pair, query)),
            )
            for source in names
            for target in names
            if source != target
            and not (source in world.image_planes and target in world.image_planes)
        ]
        self._thread = threading.Thread(target=self._serve, daemon=True, name="truth")
        self._thread.start()

    def _serve(self) -> None:
        while (item := self._queries.get()) is not None:
            source, target, query = item
            with query:
                try:
                    stamp = _timestamp(query.parameters.get("t"))
                    value = encode(truth(self.world, source, target, stamp))
                    query.reply(query.key_expr, value, encoding=MSGPACK)
                    self.answered += 1
                except TruthError as exc:
                    self.failed += 1
                    log.info("truth %s->%s: %s", source, target, exc)
                    query.reply_err(str(exc))

    def close(self) -> None:
        for queryable in self._queryables:
            queryable.undeclare()
        self._queries.put(None)
        self._thread.join(timeout=1.0)
