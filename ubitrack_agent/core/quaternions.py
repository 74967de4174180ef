"""Unit quaternions ``(x, y, z, w)``, vectorised over leading batch dimensions.

Why by hand: scipy's ``Rotation`` implements all of this, but each call on a single rotation
costs tens of microseconds of object overhead (measured 50 us for a compose, scipy 1.17.1),
and workers handle one pose at a time at kilohertz rates. Here the Hamilton product and the
rotation matrix are written as constant bilinear forms in the quaternion components, so one
``outer product @ table`` evaluates them for one quaternion or a batch alike (about 3 us for a
single product). The tests check every function against scipy.

References: Sola, "Quaternion kinematics for the error-state Kalman filter", arXiv:1711.02508
(product, rotation matrix); Shoemake, "Animating rotation with quaternion curves",
SIGGRAPH 1985 (SLERP).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])

X, Y, Z, W = range(4)


def _product_table() -> np.ndarray:
    """``P[i, j]`` = component vector of ``e_i * e_j`` for the basis quaternions (x, y, z, w)."""
    table = np.zeros((4, 4, 4))
    # Hamilton: i*j = k, j*k = i, k*i = j, i*i = j*j = k*k = -1, w is the unit.
    for a in range(4):
        table[W, a, a] = table[a, W, a] = 1.0
    for a, b, c in ((X, Y, Z), (Y, Z, X), (Z, X, Y)):
        table[a, b, c] = 1.0
        table[b, a, c] = -1.0
        table[a, a, W] = -1.0
    return table.reshape(16, 4)


def _matrix_table() -> np.ndarray:
    """``M[i, j]`` with ``R(q) = sum_ij q_i q_j M[i, j]``, from
    ``R = (w^2 - |u|^2) I + 2 u u^T + 2 w [u]x`` for ``q = (u, w)``."""
    eye = np.eye(3)
    table = np.zeros((4, 4, 3, 3))
    table[W, W] = eye
    for a in range(3):
        table[a, a] = -eye + 2.0 * np.outer(eye[a], eye[a])
        cross_matrix = np.cross(eye[a], eye).T  # column c is e_a x e_c
        table[a, W] = table[W, a] = cross_matrix
        for b in range(3):
            if b != a:
                table[a, b] = 2.0 * np.outer(eye[a], eye[b])
    return table.reshape(16, 9)


_PRODUCT = _product_table()
_MATRIX = _matrix_table()


def _outer(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    if a.shape != b.shape:
        a, b = np.broadcast_arrays(a, b)
    return (a[..., :, None] * b[..., None, :]).reshape((*a.shape[:-1], 16))


def multiply_floats(a: Sequence[float], b: Sequence[float]) -> tuple[float, ...]:
    """Hamilton product ``a * b`` of one pair of quaternions (x, y, z, w) on plain floats: for
    single poses on the data path, where each numpy call costs more than the whole product
    (``docs/performance.md``, "Data path")."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def rotate_floats(q: Sequence[float], v: Sequence[float]) -> tuple[float, ...]:
    """``R(q) v`` for one unit quaternion and one vector on plain floats, as
    ``v + 2 w (u x v) + 2 u x (u x v)`` for ``q = (u, w)`` (Sola, arXiv:1711.02508, eq. 115)."""
    x, y, z, w = q
    vx, vy, vz = v
    cx, cy, cz = y * vz - z * vy, z * vx - x * vz, x * vy - y * vx
    return (
        vx + 2.0 * (w * cx + y * cz - z * cy),
        vy + 2.0 * (w * cy + z * cx - x * cz),
        vz + 2.0 * (w * cz + x * cy - y * cx),
    )


def multiply(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Hamilton product ``q1 * q2`` (apply ``q2`` first, then ``q1``)."""
    q1, q2 = np.asarray(q1, dtype=float), np.asarray(q2, dtype=float)
    if q1.shape == q2.shape == (4,):  # one product: on floats, a third of the table's cost
        return np.array(multiply_floats(q1.tolist(), q2.tolist()))
    return _outer(q1, q2) @ _PRODUCT


def conjugate(q: np.ndarray) -> np.ndarray:
    """Conjugate, which is the inverse of a unit quaternion."""
    return np.asarray(q, dtype=float) * (-1.0, -1.0, -1.0, 1.0)


def to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4)."""
    q = np.asarray(q, dtype=float)
    if q.shape == (4,):  # one rotation: scalar maths
        x, y, z, w = q.tolist()
        return np.array(
            [
                [w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
                [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
                [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z],
            ]
        )
    return (_outer(q, q) @ _MATRIX).reshape((*q.shape[:-1], 3, 3))


def rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` (..., 3) by unit quaternions ``q`` (..., 4), broadcasting."""
    return (to_matrix(q) @ np.asarray(v, dtype=float)[..., None])[..., 0]


def from_matrix(matrix: np.ndarray) -> np.ndarray:
    """Unit quaternions of rotation matrices (scipy; projects to the nearest rotation)."""
    return Rotation.from_matrix(matrix).as_quat()


def from_rotvec(v: np.ndarray) -> np.ndarray:
    """Unit quaternions ``Exp(v)`` of rotation vectors (..., 3) (axis times angle, radians);
    the series ``sin(a/2)/a ~ 1/2 - a^2/48`` near zero."""
    v = np.asarray(v, dtype=float)
    if v.shape == (3,):  # one rotation: scalar maths, a few microseconds
        half = 0.5 * math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        scale = 0.5 - half * half / 12.0 if half < 1e-4 else math.sin(half) / (2 * half)
        return np.array([scale * v[0], scale * v[1], scale * v[2], math.cos(half)])
    half = 0.5 * np.linalg.norm(v, axis=-1, keepdims=True)
    small = half < 1e-4
    scale = np.where(small, 0.5 - half**2 / 12.0, np.sin(half) / np.where(small, 1.0, 2 * half))
    return np.concatenate((scale * v, np.cos(half)), axis=-1)


def to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vectors ``Log(q)`` (..., 3) of unit quaternions (..., 4), angle in
    ``[0, pi]`` (``q`` and ``-q`` give the same vector)."""
    q = np.asarray(q, dtype=float)
    if q.shape == (4,):  # one rotation: scalar maths
        x, y, z, w = (-q if q[3] < 0.0 else q).tolist()
        sine = math.sqrt(x * x + y * y + z * z)
        scale = 2.0 / w if sine < 1e-8 else 2.0 * math.atan2(sine, w) / sine
        return np.array([scale * x, scale * y, scale * z])
    q = np.where(q[..., 3:] < 0.0, -q, q)
    sine = np.linalg.norm(q[..., :3], axis=-1, keepdims=True)
    half = np.arctan2(sine, q[..., 3:])
    small = sine < 1e-8
    scale = np.where(
        small, 2.0 / np.where(small, q[..., 3:], 1.0), 2.0 * half / np.where(small, 1.0, sine)
    )
    return scale * q[..., :3]


def angle(q: np.ndarray) -> np.ndarray:
    """Rotation angle in radians, in ``[0, pi]``, accurate for tiny angles (atan2 form)."""
    q = np.asarray(q, dtype=float)
    return 2.0 * np.arctan2(np.linalg.norm(q[..., :3], axis=-1), np.abs(q[..., 3]))


def slerp(q0: np.ndarray, q1: np.ndarray, s: np.ndarray | float) -> np.ndarray:
    """Spherical linear interpolation from ``q0`` (s=0) to ``q1`` (s=1) along the short arc."""
    q0 = np.asarray(q0, dtype=float)
    q1 = np.asarray(q1, dtype=float)
    s = np.asarray(s, dtype=float)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0.0, -q1, q1)
    theta = np.arccos(np.clip(np.abs(dot), 0.0, 1.0))
    sin_theta = np.sin(theta)
    near = sin_theta < 1e-9
    safe = np.where(near, 1.0, sin_theta)
    w0 = np.where(near, 1.0 - s, np.sin((1.0 - s) * theta) / safe)
    w1 = np.where(near, s, np.sin(s * theta) / safe)
    q = w0 * q0 + w1 * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)
