"""Input validation shared by the algorithms: every bad input becomes a clear ``ValueError``.

The algorithms take plain numpy arrays. These helpers convert an argument to float64, check its
shape, count and finiteness, and name the argument in the message, so that callers never see
an obscure numpy or OpenCV error instead.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ubitrack_agent.core.measurements import UNIT_QUATERNION_TOLERANCE

DEGENERACY_TOLERANCE = 1e-9
"""Relative singular-value threshold below which a point set counts as degenerate."""


def as_array(name: str, value: Any, shape: tuple[int | None, ...]) -> np.ndarray:
    """``value`` as a finite float64 array of ``shape`` (``None`` = any length), or raise."""
    try:
        array = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: not an array of numbers ({exc})") from None
    if array.ndim != len(shape) or any(
        want is not None and got != want for got, want in zip(array.shape, shape, strict=True)
    ):
        want_text = "x".join("N" if d is None else str(d) for d in shape)
        raise ValueError(f"{name}: shape must be {want_text}, got {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError(f"{name}: contains NaN or infinity")
    return array


def as_points(name: str, value: Any, dim: int, minimum: int) -> np.ndarray:
    """An N x ``dim`` point array with N >= ``minimum``."""
    points = as_array(name, value, (None, dim))
    if len(points) < minimum:
        raise ValueError(f"{name}: need at least {minimum} points, got {len(points)}")
    return points


def same_count(**arrays: np.ndarray) -> int:
    """The common length of ``arrays``, or raise naming the lengths."""
    lengths = {name: len(array) for name, array in arrays.items()}
    if len(set(lengths.values())) != 1:
        raise ValueError(f"inputs must have the same number of entries, got {lengths}")
    return next(iter(lengths.values()))


def as_quaternions(name: str, value: Any, minimum: int = 1) -> np.ndarray:
    """An N x 4 array of unit quaternions (x, y, z, w)."""
    quats = as_points(name, value, 4, minimum)
    norms = np.linalg.norm(quats, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > UNIT_QUATERNION_TOLERANCE)
    if bad.size:
        raise ValueError(f"{name}: entry {bad[0]} is not a unit quaternion (norm {norms[bad[0]]})")
    return quats


def as_covariances(name: str, value: Any, count: int, size: int) -> np.ndarray:
    """``count`` symmetric positive definite ``size`` x ``size`` matrices."""
    covs = as_array(name, value, (count, size, size))
    if not np.allclose(covs, np.swapaxes(covs, 1, 2), rtol=1e-9, atol=1e-15):
        raise ValueError(f"{name}: covariances must be symmetric")
    smallest = np.linalg.eigvalsh(covs)[:, 0]
    largest = np.abs(covs).max(axis=(1, 2))
    bad = np.flatnonzero(smallest <= DEGENERACY_TOLERANCE * largest)
    if bad.size:
        raise ValueError(f"{name}: covariance {bad[0]} is not positive definite")
    return covs


def as_camera_matrix(value: Any) -> np.ndarray:
    """A 3x3 intrinsic matrix ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` with fx, fy > 0."""
    k = as_array("camera_matrix", value, (3, 3))
    if k[1, 0] != 0 or k[2, 0] != 0 or k[2, 1] != 0 or k[2, 2] != 1 or k[0, 0] <= 0 or k[1, 1] <= 0:
        raise ValueError("camera_matrix: must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]], fx, fy > 0")
    return k


def as_distortion(value: Any) -> np.ndarray:
    """OpenCV distortion coefficients (0, 4, 5, 8, 12 or 14 of them); ``None`` means none."""
    if value is None:
        return np.zeros(0)
    dist = as_array("dist_coeffs", np.ravel(value), (None,))
    if len(dist) not in (0, 4, 5, 8, 12, 14):
        raise ValueError(f"dist_coeffs: need 0, 4, 5, 8, 12 or 14 coefficients, got {len(dist)}")
    return dist


def positive(name: str, value: float) -> float:
    """``value`` as a finite float > 0."""
    number = float(value)
    if not np.isfinite(number) or number <= 0.0:
        raise ValueError(f"{name}: must be a positive number, got {value}")
    return number


def rank_of_spread(points: np.ndarray) -> int:
    """Number of significant directions (0-3) in which centred ``points`` spread."""
    centred = points - points.mean(axis=0)
    singular = np.linalg.svd(centred, compute_uv=False)
    if singular[0] == 0.0:
        return 0
    return int(np.sum(singular > DEGENERACY_TOLERANCE * 1e3 * singular[0]))


def require_spread(name: str, points: np.ndarray, rank: int, what: str) -> None:
    """Raise if ``points`` spread in fewer than ``rank`` directions (e.g. 2 = not collinear)."""
    if rank_of_spread(points) < rank:
        raise ValueError(f"{name}: degenerate geometry, the points are {what}")
