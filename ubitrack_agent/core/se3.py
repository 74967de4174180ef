"""Rigid transformations as (quaternion, translation) pairs, vectorised over batches.

A transform ``(q, t)`` maps ``x_B`` to ``x_A = R(q) x_B + t`` (the pose of B in A, see
:mod:`ubitrack_agent.core.measurements`). Every function accepts arrays with any leading batch
shape, ``(..., 4)`` and ``(..., 3)``, and broadcasts them.
"""

from __future__ import annotations

import numpy as np

from ubitrack_agent.core import quaternions

Transform = tuple[np.ndarray, np.ndarray]


def compose(q1: np.ndarray, t1: np.ndarray, q2: np.ndarray, t2: np.ndarray) -> Transform:
    """``T1 T2``: for ``T1`` = A->B and ``T2`` = B->C, the transform A->C."""
    return quaternions.multiply(q1, q2), quaternions.rotate(q1, t2) + np.asarray(t1, dtype=float)


def invert(q: np.ndarray, t: np.ndarray) -> Transform:
    """``T^-1``: for A->B, the transform B->A."""
    q_inv = quaternions.conjugate(q)
    return q_inv, -quaternions.rotate(q_inv, t)


def transform_points(q: np.ndarray, t: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map points (..., 3) given in B to A. ``q``/``t`` broadcast against the points."""
    return quaternions.rotate(q, points) + np.asarray(t, dtype=float)


def interpolate(
    q0: np.ndarray, t0: np.ndarray, q1: np.ndarray, t1: np.ndarray, s: np.ndarray | float
) -> Transform:
    """Blend two transforms: SLERP for rotation, linear for translation; ``s`` in [0, 1].

    This is the decoupled interpolation Ubitrack's interpolation buffers use (not the screw
    motion of the SE(3) geodesic); for the short gaps between tracker samples they agree to
    second order.
    """
    s_arr = np.asarray(s, dtype=float)
    t0 = np.asarray(t0, dtype=float)
    t1 = np.asarray(t1, dtype=float)
    return quaternions.slerp(q0, q1, s_arr), t0 + s_arr[..., None] * (t1 - t0)


def to_matrix(q: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Homogeneous 4x4 matrices (..., 4, 4)."""
    rotation = quaternions.to_matrix(q)
    t = np.broadcast_to(np.asarray(t, dtype=float), (*rotation.shape[:-2], 3))
    matrix = np.zeros((*rotation.shape[:-2], 4, 4))
    matrix[..., :3, :3] = rotation
    matrix[..., :3, 3] = t
    matrix[..., 3, 3] = 1.0
    return matrix


def from_matrix(matrix: np.ndarray) -> Transform:
    """``(q, t)`` of homogeneous matrices (..., 4, 4); the rotation block is orthonormalised."""
    matrix = np.asarray(matrix, dtype=float)
    return quaternions.from_matrix(matrix[..., :3, :3]), matrix[..., :3, 3].copy()
