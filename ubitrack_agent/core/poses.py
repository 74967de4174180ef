"""Operations on pose measurements that carry their covariance along.

These combine :mod:`~ubitrack_agent.core.se3` (the means) with
:mod:`~ubitrack_agent.core.uncertainty` (the covariances). A :class:`Pose` without covariance
counts as exact: combining it with an :class:`ErrorPose` gives an :class:`ErrorPose`, combining
two plain poses gives a plain pose. The result's timestamp is the later of the inputs' (a
worker that synchronised its inputs passes equal timestamps).

An :class:`ErrorPose`'s ``static_covariance`` (the share of its static edges' errors) is
carried through by the same first-order maps as the covariance, a missing one counting as
zero: the result's static part is that of its inputs' static parts (its dynamic inputs held
exact), as ``bench.fusion_consistency_bench`` computes it offline.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from typing import Any

import numpy as np

from ubitrack_agent.core import quaternions, se3, uncertainty
from ubitrack_agent.core.errors import ExtrapolationError
from ubitrack_agent.core.measurements import ErrorPose, Measurement, Pose, Position3D

AnyPose = Pose | ErrorPose

_ZERO6 = np.zeros((6, 6))
_FOUR_FLOATS, _THREE_FLOATS = struct.Struct("4d"), struct.Struct("3d")
"""Native float64: ``np.frombuffer`` reads them back as they are."""


def _covariance(pose: AnyPose) -> np.ndarray | None:
    return pose.covariance if isinstance(pose, ErrorPose) else None


def _static(pose: AnyPose) -> np.ndarray | None:
    return pose.static_covariance if isinstance(pose, ErrorPose) else None


def _make(
    timestamp_ns: int,
    q: np.ndarray,
    t: np.ndarray,
    cov: np.ndarray | None,
    static: np.ndarray | None = None,
) -> AnyPose:
    """The result pose. ``cov`` (``A Sigma A^T`` sums, or blends) is symmetric to round-off,
    about 1e-16 relative, far inside the validation's 1e-9: it is not symmetrised again, two
    numpy calls fewer on every hop (``docs/performance.md``, "Data path"); so is ``static``."""
    if cov is None:
        return Pose.derived(timestamp_ns=timestamp_ns, rotation=q, translation=t)
    return ErrorPose.derived(
        timestamp_ns=timestamp_ns,
        rotation=q,
        translation=t,
        covariance=cov,
        static_covariance=static,
    )


def _transported(
    first: np.ndarray | None, second: np.ndarray | None, adj: np.ndarray, adj_t: np.ndarray
) -> np.ndarray | None:
    """``first + Ad second Ad^T`` (either None counting as zero; both None: None), read-only:
    a concatenation's covariance, or its static part."""
    if first is None and second is None:
        return None
    cov = (_ZERO6 if first is None else first) + adj @ (
        _ZERO6 if second is None else second
    ) @ adj_t
    cov.setflags(write=False)
    return cov


def _compose_means(
    q1: list[float], t1: list[float], second: AnyPose
) -> tuple[np.ndarray, np.ndarray]:
    """``(q1 q2, R(q1) t2 + t1)`` on plain floats, as read-only arrays: the means of a
    concatenation, which every pattern hop computes per sample. Why not :func:`se3.compose`:
    each numpy call costs a microsecond warm and about ten on a CPU woken for the sample among
    other processes (``docs/performance.md``, "Data path"); these are four (two ``tolist``, two
    ``frombuffer`` over the packed bytes, read-only as a measurement's arrays must be)."""
    moved = quaternions.rotate_floats(q1, second.translation.tolist())
    q = quaternions.multiply_floats(q1, second.rotation.tolist())
    t = (moved[0] + t1[0], moved[1] + t1[1], moved[2] + t1[2])
    return np.frombuffer(_FOUR_FLOATS.pack(*q)), np.frombuffer(_THREE_FLOATS.pack(*t))


def with_static_error(pose: Measurement) -> Measurement:
    """``pose`` with its whole covariance marked static (``ErrorPose.static_covariance``): a
    static edge's error (a calibration's, a survey's) is the same in every sample computed from
    it. Any other measurement, or a pose so marked already, as it is."""
    if type(pose) is not ErrorPose or pose.static_covariance is pose.covariance:
        return pose
    return ErrorPose.unchecked({**pose.__dict__, "static_covariance": pose.covariance})


def invert_pose(pose: AnyPose) -> AnyPose:
    """The inverse edge (B->A from A->B), covariance transported exactly."""
    q, t = se3.invert(pose.rotation, pose.translation)
    cov, static = _covariance(pose), _static(pose)
    if cov is not None:
        cov = uncertainty.invert_covariance(pose.rotation, pose.translation, cov)
    if static is not None:
        static = uncertainty.invert_covariance(pose.rotation, pose.translation, static)
    return _make(pose.timestamp_ns, q, t, cov, static)


def compose_poses(first: AnyPose, second: AnyPose) -> AnyPose:
    """Concatenation A->C of ``first`` = A->B and ``second`` = B->C (independent errors):
    ``Sigma_1 + Ad_T1 Sigma_2 Ad_T1^T`` (:mod:`~ubitrack_agent.core.uncertainty`). The result
    is built unchecked (``Measurement.unchecked``: its arrays are made here, float64 of the
    type's shapes, read-only) and its covariance is not symmetrised again (see :func:`_make`)."""
    timestamp_ns = max(first.timestamp_ns, second.timestamp_ns)
    cov1, cov2 = getattr(first, "covariance", None), getattr(second, "covariance", None)
    if cov1 is None and cov2 is None:
        q, t = _compose_means(first.rotation.tolist(), first.translation.tolist(), second)
        return Pose.unchecked({"timestamp_ns": timestamp_ns, "rotation": q, "translation": t})
    q1, t1, adj, adj_transposed = _kept(first)
    q, t = _compose_means(q1, t1, second)
    static1 = getattr(first, "static_covariance", None)
    static2 = getattr(second, "static_covariance", None)
    return ErrorPose.unchecked(
        {
            "timestamp_ns": timestamp_ns,
            "rotation": q,
            "translation": t,
            "covariance": _transported(cov1, cov2, adj, adj_transposed),
            "static_covariance": _transported(static1, static2, adj, adj_transposed),
        }
    )


def compose_pose_pairs(firsts: Sequence[AnyPose], seconds: Sequence[AnyPose]) -> list[AnyPose]:
    """:func:`compose_poses` of each pair, equal to round-off. Where every first pose holds
    the same arrays (a static edge, restamped for each instant) and the second poses are of
    one type, by a few numpy calls over the stacked second poses instead of a dozen per pair:
    for a worker draining a backlog (``ubitrack_agent.services.worker``, ``docs/performance.md``,
    "Data path"). Each result's arrays are read-only rows of the run's."""
    first, kind = firsts[0], type(seconds[0])
    cov1, static1 = getattr(first, "covariance", None), getattr(first, "static_covariance", None)
    statics2 = [getattr(b, "static_covariance", None) for b in seconds]
    if (
        len(seconds) < 2
        or any(
            type(a) is not type(first)
            or a.rotation is not first.rotation
            or a.translation is not first.translation
            or getattr(a, "covariance", None) is not cov1
            or getattr(a, "static_covariance", None) is not static1
            or type(b) is not kind
            for a, b in zip(firsts, seconds, strict=True)
        )
        or len({static is None for static in statics2}) > 1  # some with a static part, some not
    ):
        return [compose_poses(a, b) for a, b in zip(firsts, seconds, strict=True)]
    _, t1, adj, adj_transposed = _kept(first)
    rotations = np.stack([b.rotation for b in seconds])
    translations = np.stack([b.translation for b in seconds])
    q = quaternions.multiply(first.rotation, rotations)
    t = translations @ quaternions.to_matrix(first.rotation).T + t1
    arrays = {"rotation": q, "translation": t}
    if kind is ErrorPose:
        covs = adj @ np.stack([b.covariance for b in seconds]) @ adj_transposed
        arrays["covariance"] = covs if cov1 is None else covs + cov1
    elif cov1 is not None:
        arrays["covariance"] = np.broadcast_to(cov1, (len(seconds), 6, 6))
    if statics2[0] is not None:
        statics = adj @ np.stack(statics2) @ adj_transposed
        arrays["static_covariance"] = statics if static1 is None else statics + static1
    elif static1 is not None:
        arrays["static_covariance"] = np.broadcast_to(static1, (len(seconds), 6, 6))
    for array in arrays.values():
        array.flags.writeable = False
    if "covariance" not in arrays:
        result: type[AnyPose] = Pose
    else:
        result = ErrorPose
        arrays.setdefault("static_covariance", None)  # type: ignore[arg-type]
    return [
        result.unchecked(
            {
                "timestamp_ns": max(a.timestamp_ns, b.timestamp_ns),
                **{name: None if array is None else array[j] for name, array in arrays.items()},
            }
        )
        for j, (a, b) in enumerate(zip(firsts, seconds, strict=True))
    ]


_KEPT: dict[tuple[int, int], tuple[Any, ...]] = {}
_KEPT_POSES = 16


def _kept(pose: AnyPose) -> tuple[list[float], list[float], np.ndarray, np.ndarray]:
    """The rotation and translation of ``pose`` as floats, ``Ad_T`` and its transpose, kept by
    the identity of its arrays (for up to :data:`_KEPT_POSES` poses, then all forgotten at
    once: no iteration that another thread could disturb): a measurement's arrays are
    read-only, and a restamped one shares them, so the static edge a concatenation composes
    with on every sample (its buffer's value, restamped) costs its covariance's products and
    sum, not an adjoint and two ``tolist`` (``docs/performance.md``, "Data path"). An entry
    holds the arrays themselves, so their ids are not reused while it is kept."""
    q, t = pose.rotation, pose.translation
    key = (id(q), id(t))
    entry = _KEPT.get(key)
    if entry is None:
        adj = uncertainty.adjoint(q, t)
        adj.flags.writeable = False
        entry = (q, t, q.tolist(), t.tolist(), adj, adj.T)
        if len(_KEPT) >= _KEPT_POSES:
            _KEPT.clear()
        _KEPT[key] = entry
    return entry[2], entry[3], entry[4], entry[5]


def transform_position(pose: AnyPose, point: Position3D) -> Position3D:
    """Concatenation of A->B (pose) with B->P (position): the position of P in A.

    Covariance: ``R Sigma_p R^T + J Sigma_T J^T`` with ``J = [-[x']x, I]``, the Jacobian of
    ``Exp(xi) x'`` at ``xi = 0`` for the left perturbation of the pose.
    """
    x = se3.transform_points(pose.rotation, pose.translation, point.position)
    cov_pose, cov_point = _covariance(pose), point.covariance
    cov = None
    if cov_pose is not None or cov_point is not None:
        cov = np.zeros((3, 3))
        if cov_point is not None:
            rotation = se3.quaternions.to_matrix(pose.rotation)
            cov += rotation @ cov_point @ rotation.T
        if cov_pose is not None:
            jacobian = np.hstack((-uncertainty.skew(x), np.eye(3)))
            cov += jacobian @ cov_pose @ jacobian.T
        cov = 0.5 * (cov + cov.T)
    return Position3D.derived(
        timestamp_ns=max(pose.timestamp_ns, point.timestamp_ns), position=x, covariance=cov
    )


def interpolate_pose(before: AnyPose, after: AnyPose, timestamp_ns: int) -> AnyPose:
    """The pose at ``timestamp_ns`` between two samples: SLERP and linear translation.

    Covariance by :func:`~ubitrack_agent.core.uncertainty.interpolate_covariance` (the linear
    blend). Raises :class:`ExtrapolationError` outside ``[before, after]``.
    """
    t0, t1 = before.timestamp_ns, after.timestamp_ns
    if not t0 <= timestamp_ns <= t1:
        raise ExtrapolationError(f"timestamp {timestamp_ns} outside [{t0}, {t1}]")
    s = 0.0 if t1 == t0 else (timestamp_ns - t0) / (t1 - t0)
    q, t = se3.interpolate(
        before.rotation, before.translation, after.rotation, after.translation, s
    )
    return _make(
        timestamp_ns,
        q,
        t,
        _blended(_covariance(before), _covariance(after), s),
        _blended(_static(before), _static(after), s),
    )


def _blended(before: np.ndarray | None, after: np.ndarray | None, s: float) -> np.ndarray | None:
    """The covariance (or static part) of an interpolated pose: the linear blend of the two
    (either None counting as zero; both None: None)."""
    if before is None and after is None:
        return None
    return uncertainty.interpolate_covariance(
        _ZERO6 if before is None else before, _ZERO6 if after is None else after, s
    )
