"""A generated building: the SRG a site of many tracked rooms announces (issue [scale]).

Each room ``r`` has a room frame ``R<r>`` placed in the building frame ``B`` by a static survey
edge (the *star*); in the *corridor* layout each room is also surveyed to the next one
(``R<r> -> R<r+1>``, static), which closes a cycle through ``B`` for every pair of neighbours.
In a room:

* an outside-in tracker ``T<r>`` and ``redundant`` more ``T<r>_<k>``, each static in the room
  (``R<r> -> T<r>...``, 6D) and each tracking every body ``H<r>_<j>`` (dynamic 6D, provider the
  tracker), as A.R.T.'s tracker tracks the head target of the paper's figure 1;
* ``cameras`` of the bodies (``C<r>_<j>`` rigid on ``H<r>_<j>``, static 6D; its image plane
  ``I<r>_<j>``, static 3x4) see the room's marker target ``M<r>`` (static in the room) by
  ``features`` 2D features ``F<r>_<f>`` (``I -> F`` dynamic 2D, provider the camera; ``M -> F``
  static 3D): the loop of the paper's figure 1 in every room;
* ``shared_targets``: each camera of room ``r`` also sees the marker of room ``r+1`` through
  the door (its 2D features ``I<r>_<j> -> F<r+1>_<f>``), a target shared between rooms;
* ``alike``: every room is equipped alike (the default), so the planner plans one room's part
  for all (``graph.planner.PartCache``); without, room ``r``'s trackers announce an error
  ``r`` percent larger, and each room is planned on its own.

Everything static is a database edge, as a calibration store would serve it. The generator is
pure (no randomness): the same arguments give the same SRG, edge ids included.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import networkx as nx

from ubitrack_agent.graph.srg import Quality, add_measured_edge, new_srg

TRACKER = Quality(variance=(0.5e-3) ** 2, rate=60.0, latency=0.005)
"""An outside-in tracker's body pose: 0.5 mm, 60 Hz, 5 ms."""
FEATURE = Quality(variance=(1e-3) ** 2, rate=30.0, latency=0.02)
"""A camera's 2D feature: 1 mm induced error, 30 Hz, 20 ms."""
SURVEY = Quality(variance=(1e-3) ** 2, rate=0.0, latency=0.0)
"""A static calibration or survey: 1 mm."""


@dataclass(frozen=True)
class Building:
    """The shape of a generated building (module docstring)."""

    rooms: int = 1
    bodies: int = 1
    redundant: int = 0
    cameras: int = 1
    features: int = 5
    layout: str = "star"
    shared_targets: bool = False
    alike: bool = True

    def __post_init__(self) -> None:
        if self.layout not in ("star", "corridor"):
            raise ValueError(f"layout must be star or corridor, got {self.layout!r}")
        if self.rooms < 1 or self.bodies < 1 or self.redundant < 0 or self.features < 0:
            raise ValueError("rooms and bodies >= 1, redundant and features >= 0")
        if not 0 <= self.cameras <= self.bodies:
            raise ValueError("cameras must be between 0 and the number of bodies")


def room(r: int) -> str:
    return f"R{r}"


def tracker(r: int, k: int = 0) -> str:
    """Room ``r``'s outside-in tracker (``k = 0``) or its ``k``-th redundant tracker."""
    return f"T{r}" if k == 0 else f"T{r}_{k}"


def body(r: int, j: int = 1) -> str:
    return f"H{r}_{j}"


def camera(r: int, j: int = 1) -> str:
    return f"C{r}_{j}"


def image(r: int, j: int = 1) -> str:
    """The image plane of camera ``camera(r, j)``."""
    return f"I{r}_{j}"


def marker(r: int) -> str:
    return f"M{r}"


def feature(r: int, f: int) -> str:
    """The ``f``-th feature (from 1) of room ``r``'s marker target."""
    return f"F{r}_{f}"


def build(shape: Building) -> nx.MultiDiGraph:
    """The SRG of ``shape`` (module docstring): per room O((redundant + 1) * bodies + cameras *
    features) edges, so O(rooms * that) in all, built in time linear in its edges."""
    srg = new_srg()

    def static(a: str, b: str, edge_type: str = "6D") -> None:
        add_measured_edge(srg, a, b, edge_type, static=True, quality=SURVEY)

    for r in range(shape.rooms):
        static("B", room(r))
        if shape.layout == "corridor" and r + 1 < shape.rooms:
            static(room(r), room(r + 1))
        static(room(r), marker(r))
        for f in range(1, shape.features + 1):
            static(marker(r), feature(r, f), "3D")
        worse = 1.0 if shape.alike else (1 + r / 100) ** 2
        pose = replace(TRACKER, variance=TRACKER.variance * worse)
        for k in range(shape.redundant + 1):
            t = tracker(r, k)
            static(room(r), t)
            for j in range(1, shape.bodies + 1):
                add_measured_edge(srg, t, body(r, j), "6D", provider=t, quality=pose)
        for j in range(1, shape.cameras + 1):
            c, plane = camera(r, j), image(r, j)
            static(c, body(r, j))
            static(c, plane, "3x4")
            seen = [r, r + 1] if shape.shared_targets and r + 1 < shape.rooms else [r]
            for s in seen:
                for f in range(1, shape.features + 1):
                    add_measured_edge(srg, plane, feature(s, f), "2D", provider=c, quality=FEATURE)
    return srg
