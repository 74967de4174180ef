"""Where the frames are: every frame of the SRG placed relative to a root by the live relations
(each measured edge and each running component's output at one display time,
:mod:`.align`), for the 3D view. Pure: :mod:`ubitrack_agent.commands.view.frame_watch`
supplies the values.

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

from ubitrack_agent.core import uncertainty
from ubitrack_agent.core.measurements import ErrorPose, Measurement, Pose, Position3D
from ubitrack_agent.core.poses import compose_poses, invert_pose, transform_position

IDENTITY = Pose(0, np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3))


@dataclass(frozen=True)
class LiveRelation:
    """The value of a relation ``source`` -> ``target`` at the display time, ``derived`` by a
    component (else measured by a provider), by its ``name`` (an edge id or a component's
    instance); ``skew_ns``: how far from the display time it was measured (:mod:`.align`)."""

    source: str
    target: str
    sample: Measurement
    derived: bool
    name: str
    skew_ns: int = 0


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
    "via" (the relations composed), "skew_ms" (the largest skew of those)}}, "unplaced":
    {name: why}}``."""
    poses: dict[str, tuple[Pose | ErrorPose, list[str], int]] = {root: (IDENTITY, [], 0)}
    links: dict[str, list[tuple[str, LiveRelation, bool]]] = defaultdict(list)
    points: list[LiveRelation] = []
    for relation in relations:
        if isinstance(relation.sample, Pose | ErrorPose):
            links[relation.source].append((relation.target, relation, False))
            links[relation.target].append((relation.source, relation, True))
        elif isinstance(relation.sample, Position3D):
            points.append(relation)
    # Dijkstra on (hops, measured hops): a component's output wins a tie.
    queue: list[tuple[int, int, str]] = [(0, 0, root)]
    best = {root: (0, 0)}
    parent: dict[str, tuple[str, LiveRelation, bool]] = {}
    while queue:
        hops, measured, frame = heapq.heappop(queue)
        if best.get(frame) != (hops, measured):
            continue
        for neighbour, relation, inverted in links[frame]:
            cost = (hops + 1, measured + (not relation.derived))
            if cost < best.get(neighbour, (1 << 30, 0)):
                best[neighbour] = cost
                parent[neighbour] = (frame, relation, inverted)
                heapq.heappush(queue, (*cost, neighbour))
    for frame in sorted(best, key=best.__getitem__):
        if frame == root:
            continue
        above, relation, inverted = parent[frame]
        pose, via, skew = poses[above]
        step = invert_pose(relation.sample) if inverted else relation.sample  # type: ignore[arg-type]
        poses[frame] = (
            compose_poses(pose, step),
            [*via, relation.name + (" inverted" if inverted else "")],
            max(skew, relation.skew_ns),
        )
    placed = {frame: _pose_json(pose, via, skew) for frame, (pose, via, skew) in poses.items()}
    covariances = {frame: _position_covariance(pose) for frame, (pose, _, _) in poses.items()}
    for relation in points:
        if relation.target not in placed and relation.source in poses:
            pose, via, skew = poses[relation.source]
            point = transform_position(pose, relation.sample)  # type: ignore[arg-type]
            skew = max(skew, relation.skew_ns)
            placed[relation.target] = _point_json(point, [*via, relation.name], skew)
            covariances[relation.target] = point.covariance
    uncertain = [frame for frame, covariance in covariances.items() if covariance is not None]
    shapes = ellipsoids([covariances[frame] for frame in uncertain])
    for frame, shape in zip(uncertain, shapes, strict=True):
        placed[frame]["ellipsoid"] = shape
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


def _position_covariance(pose: Pose | ErrorPose) -> np.ndarray | None:
    """The covariance of ``pose``'s origin (its translation) under the left perturbation:
    ``d t = -[t]x phi + rho``, so ``J Sigma J^T`` with ``J = [-[t]x, I]``."""
    if not isinstance(pose, ErrorPose):
        return None
    jacobian = np.hstack((-uncertainty.skew(pose.translation), np.eye(3)))
    return jacobian @ pose.covariance @ jacobian.T


def _pose_json(pose: Pose | ErrorPose, via: list[str], skew_ns: int) -> dict[str, Any]:
    return {
        "position": _floats(pose.translation),
        "rotation": _floats(pose.rotation),
        "ellipsoid": None,
        "via": via,
        "skew_ms": round(skew_ns / 1e6, 3),
    }


def _point_json(point: Position3D, via: list[str], skew_ns: int) -> dict[str, Any]:
    return {
        "position": _floats(point.position),
        "rotation": None,
        "ellipsoid": None,
        "via": via,
        "skew_ms": round(skew_ns / 1e6, 3),
    }


def ellipsoids(covariances: Sequence[np.ndarray]) -> list[dict[str, Any]]:
    """The one-sigma ellipsoid of each 3x3 position covariance (m^2): its ``radii`` (m, the
    square roots of the eigenvalues) and its ``axes``, the unit eigenvectors (a right-handed
    basis, each axis with its radius). One stacked eigendecomposition for all."""
    if not covariances:
        return []
    stack = np.stack(covariances)
    values, vectors = np.linalg.eigh(0.5 * (stack + stack.transpose(0, 2, 1)))
    vectors[np.linalg.det(vectors) < 0, :, 0] *= -1.0
    radii = np.sqrt(np.clip(values, 0.0, None)).round(6).tolist()
    axes = vectors.transpose(0, 2, 1).round(6).tolist()
    return [{"radii": r, "axes": a} for r, a in zip(radii, axes, strict=True)]


def ellipsoid(covariance: np.ndarray | None) -> dict[str, Any] | None:
    """:func:`ellipsoids` of one covariance; None without one."""
    return None if covariance is None else ellipsoids([covariance])[0]


def _floats(array: np.ndarray) -> list[float]:
    return np.round(array, 6).tolist()
