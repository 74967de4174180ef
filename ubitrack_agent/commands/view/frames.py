"""Where the frames are: every frame of the SRG placed relative to a root by the live relations
(the latest sample of each measured edge and of each running component's output), for the
3D view. Pure: :mod:`ubitrack_agent.commands.view.frame_watch` supplies the samples.

The SRG's edges are spatial relations between frames (Pustka et al. 2006, section 2): a 6D
edge A->B is the pose of B in A, a 3D edge A->B the position of B in A. Placing every frame
relative to the root is the paper's concatenation and inversion along a path (section 3), here
along a breadth-first spanning tree of the 6D relations from the root (fewest hops; of equally
short paths, one through a component's output first: a fusion's result rather than one
tracker's), with covariances carried by :func:`~ubitrack_agent.core.poses.compose_poses` and
:func:`~ubitrack_agent.core.poses.invert_pose` (first-order, Barfoot & Furgale 2014). A frame
reached only by a 3D relation gets a position and no axes
(:func:`~ubitrack_agent.core.poses.transform_position`). A frame with no 6D or 3D path to the
root (an image plane, reached by 2D and 3x4 relations only) is listed with why it is not placed.

O((frames + relations) log relations) per placement: one heap-ordered search, one composition
per placed frame (``bench/view_frames_bench.py``).
"""

from __future__ import annotations

import heapq
from collections import Counter, defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ubitrack_agent.core import quaternions, uncertainty
from ubitrack_agent.core.measurements import ErrorPose, Measurement, Pose, Position3D
from ubitrack_agent.core.poses import compose_poses, invert_pose, transform_position

IDENTITY = Pose(0, np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3))


@dataclass(frozen=True)
class LiveRelation:
    """The latest sample of a relation ``source`` -> ``target``, ``derived`` by a component
    (else measured by a provider), by its ``name`` (an edge id or a component's instance)."""

    source: str
    target: str
    sample: Measurement
    derived: bool
    name: str


def srg_frames(srg: Iterable[dict[str, Any]]) -> list[str]:
    """The frames an agent's status's ``srg`` names, sorted (malformed edges left out)."""
    frames = set()
    for edge in srg:
        if isinstance(edge, dict):
            frames.update(
                name for name in (edge.get("from"), edge.get("to")) if isinstance(name, str)
            )
    return sorted(frames)


def tracker_frame(srg: Iterable[dict[str, Any]]) -> str | None:
    """The tracker's frame, the 3D view's default root: the frame that is the source of the
    most dynamic measured 6D edges (an outside-in tracker's frame; ``ART`` in figure 1), else
    the source of the most 6D edges, else of the most edges; ties by name. None without edges."""
    edges = [edge for edge in srg if isinstance(edge, dict) and isinstance(edge.get("from"), str)]
    for wanted in (
        lambda e: e.get("type") == "6D" and not e.get("static"),
        lambda e: e.get("type") == "6D",
        lambda e: True,
    ):
        sources = Counter(edge["from"] for edge in edges if wanted(edge))
        if sources:
            return min(sources, key=lambda frame: (-sources[frame], frame))
    return None


def place(frames: Iterable[str], relations: Sequence[LiveRelation], root: str) -> dict[str, Any]:
    """Every frame of ``frames`` (and of ``relations``) relative to ``root``, as the 3D view's
    ``/frames.json`` serves it: ``{"root", "frames": {name: {"position", "rotation" (x, y, z,
    w; None for a frame placed by a position only), "ellipsoid" (None without a covariance),
    "via" (the relations composed)}}, "unplaced": {name: why}}``."""
    poses: dict[str, tuple[Pose | ErrorPose, list[str]]] = {root: (IDENTITY, [])}
    links: dict[str, list[tuple[str, Pose | ErrorPose, bool, str]]] = defaultdict(list)
    points: list[LiveRelation] = []
    for relation in relations:
        if isinstance(relation.sample, Pose | ErrorPose):
            name = relation.name
            links[relation.source].append((relation.target, relation.sample, False, name))
            links[relation.target].append((relation.source, relation.sample, True, name))
        elif isinstance(relation.sample, Position3D):
            points.append(relation)
    derived = {relation.name for relation in relations if relation.derived}
    # Dijkstra on (hops, measured hops): a component's output wins a tie.
    queue: list[tuple[int, int, str]] = [(0, 0, root)]
    best = {root: (0, 0)}
    parent: dict[str, tuple[str, Pose | ErrorPose, bool, str]] = {}
    while queue:
        hops, measured, frame = heapq.heappop(queue)
        if best.get(frame) != (hops, measured):
            continue
        for neighbour, sample, inverted, name in links[frame]:
            cost = (hops + 1, measured + (name not in derived))
            if cost < best.get(neighbour, (1 << 30, 0)):
                best[neighbour] = cost
                parent[neighbour] = (frame, sample, inverted, name)
                heapq.heappush(queue, (*cost, neighbour))
    for frame in sorted(best, key=best.__getitem__):
        if frame == root:
            continue
        above, sample, inverted, name = parent[frame]
        pose, via = poses[above]
        step = invert_pose(sample) if inverted else sample
        poses[frame] = (compose_poses(pose, step), [*via, name + (" inverted" if inverted else "")])
    placed = {frame: _pose_json(pose, via) for frame, (pose, via) in poses.items()}
    for relation in points:
        if relation.target not in placed and relation.source in poses:
            pose, via = poses[relation.source]
            point = transform_position(pose, relation.sample)  # type: ignore[arg-type]
            placed[relation.target] = _point_json(point, [*via, relation.name])
    known = {*frames, *(r.source for r in relations), *(r.target for r in relations)}
    unplaced = sorted(known - set(placed))
    return {
        "root": root,
        "frames": placed,
        "unplaced": {frame: _why_unplaced(frame, relations) for frame in unplaced},
    }


def _why_unplaced(frame: str, relations: Sequence[LiveRelation]) -> str:
    spatial = [
        r
        for r in relations
        if frame in (r.source, r.target) and isinstance(r.sample, Pose | ErrorPose | Position3D)
    ]
    if not spatial:
        return "no live 6D or 3D relation touches it (none yet, or only 2D and 3x4 ones)"
    return "its live 6D and 3D relations do not connect it to the root"


def _pose_json(pose: Pose | ErrorPose, via: list[str]) -> dict[str, Any]:
    covariance = None
    if isinstance(pose, ErrorPose):
        # The origin's position under the left perturbation: d t = -[t]x phi + rho.
        t = pose.translation
        jacobian = np.hstack((-uncertainty.skew(t), np.eye(3)))
        covariance = jacobian @ pose.covariance @ jacobian.T
    return {
        "position": _floats(pose.translation),
        "rotation": _floats(pose.rotation),
        "ellipsoid": ellipsoid(covariance),
        "via": via,
    }


def _point_json(point: Position3D, via: list[str]) -> dict[str, Any]:
    return {
        "position": _floats(point.position),
        "rotation": None,
        "ellipsoid": ellipsoid(point.covariance),
        "via": via,
    }


def ellipsoid(covariance: np.ndarray | None) -> dict[str, Any] | None:
    """The one-sigma ellipsoid of a 3x3 position covariance (m^2): its ``radii`` (m, the
    square roots of the eigenvalues) and the ``rotation`` (x, y, z, w) taking its axes to the
    eigenvectors; None without a covariance."""
    if covariance is None:
        return None
    values, vectors = np.linalg.eigh(0.5 * (covariance + covariance.T))
    if np.linalg.det(vectors) < 0:
        vectors[:, 0] = -vectors[:, 0]
    return {
        "radii": _floats(np.sqrt(np.clip(values, 0.0, None))),
        "rotation": _floats(quaternions.from_matrix(vectors)),
    }


def _floats(array: np.ndarray) -> list[float]:
    return [round(float(value), 6) for value in array]
