"""Tip (pivot) calibration: the tip of a tracked pointer in its marker and the pivot point.

The pointer's tip rests on a fixed point while the user pivots it; the tracker reports N >= 3
poses ``(R_i, t_i)`` of the marker M in the tracker W. Every pose maps the same tip ``p_m`` (in
M) to the same pivot ``p_w`` (in W)::

    R_i p_m + t_i = p_w,   stacked   [R_i, -I] (p_m, p_w) = -t_i.

This is Ubitrack's ``TipCalibration`` (``Algorithm::ToolTip::estimatePosition3D_6D``, after
Tuceryan et al., "Calibration requirements and procedures for a monitor-based augmented
reality system", IEEE TVCG 1(3), 1995), the "algebraic one step" method of Yaniv, "Which pivot
calibration?", Proc. SPIE 9415, 2015. Here the least squares is weighted and comes with a
covariance:

* With the poses' 6x6 left-perturbation covariances ``Sigma_i``: a measured pose
  ``Exp(xi_i) T_i`` moves the tip to ``p_w + [-[p_w]x, I] xi_i``, so residual ``i`` has the
  covariance ``S_i = J Sigma_i J^T``, ``J = [-[p_w]x, I]``. Generalised least squares with
  weights ``S_i^-1`` (re-evaluated at the new ``p_w`` until it settles); the covariance of
  ``(p_m, p_w)`` is ``(sum A_i^T S_i^-1 A_i)^-1``, ``A_i = [R_i, -I]`` (first order; it is the
  Cramér-Rao bound of this model evaluated at the estimate).
* Without them: the tip's scatter seen in the marker, ``R_i^T r_i``, is taken as the same
  for every sample and axially symmetric about the tip direction ``u = p_m / |p_m|``:
  variance ``a`` along ``u`` and ``b`` across it, estimated from the residuals with N - 2 and
  2 (N - 2) degrees of freedom (3N residuals, 6 unknowns). It is exactly the scatter of a
  tracker with isotropic noise (``a = s_t^2``, ``b = s_t^2 + s_r^2 |p_m|^2``: the rotation noise
  acts through the lever arm ``p_m``); one common covariance in the tracker frame or a single
  variance understate the covariance by about 40 % in the Monte Carlo tests, because the lever
  arm turns with the pointer.

The rotations must span at least two axes: about a single axis, the tip's component along that
axis is undetermined (``ValueError``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from ubitrack_agent.services.algorithms._checks import (
    as_covariances,
    as_points,
    as_quaternions,
    same_count,
)
from ubitrack_agent.services.algorithms.estimate import point_jacobian, symmetric

_MAX_ITERATIONS = 50
_CONVERGED = 1e-12
"""Largest change (m, or the inputs' unit) of ``(p_m, p_w)`` at which the iteration stops."""
_VARIANCE_FLOOR = 1e-30
"""Smallest residual variance estimated, so that exact data stay solvable."""


class TipSolution(NamedTuple):
    """The result of :func:`tip_calibration` (lengths in the unit of the translations)."""

    tip_in_marker: np.ndarray
    """``p_m`` (3,): the tip in the marker's frame."""
    pivot_in_tracker: np.ndarray
    """``p_w`` (3,): the pivot point in the tracker's frame."""
    tip_covariance: np.ndarray
    """3x3 covariance of ``p_m``."""
    pivot_covariance: np.ndarray
    """3x3 covariance of ``p_w``."""
    cross_covariance: np.ndarray
    """3x3 ``Cov(p_m, p_w)``."""
    rms_residual: float
    """RMS of ``|R_i p_m + t_i - p_w|``: how far the samples put the tip from the pivot."""
    noise_from_residuals: bool
    """True if no input covariances were given and the noise was estimated from residuals."""


def _require_two_axes(rotations: np.ndarray, min_spread: float) -> None:
    """Raise unless the rotations deviate from any single-axis family by ``min_spread`` (rad).

    ``(1/N) sum (R_i - R_mean)^T (R_i - R_mean)`` is, for small rotations with covariance ``C``
    of their rotation vectors, ``tr(C) I - C``; its smallest eigenvalue is the sum of the two
    smallest variances of ``C`` (zero for rotations about one axis).
    """
    deviations = rotations - rotations.mean(axis=0)
    spread = np.einsum("nji,njk->ik", deviations, deviations) / len(rotations)
    weakest = float(np.sqrt(max(np.linalg.eigvalsh(spread)[0], 0.0)))
    if weakest < min_spread:
        raise ValueError(
            "degenerate motion: the rotations turn about one axis only (RMS rotation about the "
            f"other axes {np.degrees(weakest):.3g} deg < {np.degrees(min_spread):.3g} deg); "
            "pivot the pointer about two different axes"
        )


def _residual_covariances(
    rotations: np.ndarray,
    residuals: np.ndarray,
    tip: np.ndarray,
    pivot: np.ndarray,
    pose_covariances: np.ndarray | None,
) -> np.ndarray:
    """Covariances (N x 3 x 3) of the residuals ``R_i p_m + t_i - p_w`` (module docstring)."""
    if pose_covariances is not None:
        jacobian = point_jacobian(pivot[None])[0]
        return jacobian @ pose_covariances @ jacobian.T
    in_marker = np.einsum("nji,nj->ni", rotations, residuals)
    length = np.linalg.norm(tip)
    axis = tip / length if length > 0.0 else np.zeros(3)
    along = in_marker @ axis
    across = in_marker - np.outer(along, axis)
    dof = len(residuals) - 2.0
    variance_along = max(float(np.sum(np.square(along))) / dof, _VARIANCE_FLOOR)
    variance_across = max(float(np.sum(np.square(across))) / (2.0 * dof), _VARIANCE_FLOOR)
    projector = np.outer(axis, axis)
    local = variance_along * projector + variance_across * (np.eye(3) - projector)
    return rotations @ local @ np.swapaxes(rotations, 1, 2)


def tip_calibration(
    rotations: np.ndarray,
    translations: np.ndarray,
    covariances: np.ndarray | None = None,
    min_spread_deg: float = 2.0,
) -> TipSolution:
    """Tip in the marker and pivot in the tracker from N >= 3 marker poses (module docstring).

    ``rotations`` N x 4 (x, y, z, w) and ``translations`` N x 3: the marker in the tracker.
    ``covariances``: the poses' 6x6 left-perturbation covariances (N x 6 x 6, or one 6x6 for
    every sample), or ``None`` to estimate the noise from the residuals. ``min_spread_deg``: the
    least RMS rotation (degrees, small-angle) about the axes other than the main one; below it
    the motion counts as a rotation about one axis and ``ValueError`` is raised.
    """
    q = as_quaternions("rotations", rotations, 3)
    t = as_points("translations", translations, 3, 3)
    n = same_count(rotations=q, translations=t)
    pose_covariances = None
    if covariances is not None:
        array = np.asarray(covariances, dtype=float)
        if array.shape == (6, 6):
            array = np.broadcast_to(array, (n, 6, 6))
        pose_covariances = as_covariances("covariances", array, n, 6)
    matrices = Rotation.from_quat(q).as_matrix()
    _require_two_axes(matrices, np.radians(min_spread_deg))
    design = np.concatenate((matrices, np.broadcast_to(-np.eye(3), (n, 3, 3))), axis=2)
    solution = np.linalg.lstsq(design.reshape(-1, 6), -t.ravel(), rcond=None)[0]
    for _ in range(_MAX_ITERATIONS):
        residuals = design @ solution + t
        weights = np.linalg.inv(
            _residual_covariances(matrices, residuals, solution[:3], solution[3:], pose_covariances)
        )
        weighted_design = weights @ design
        information = np.einsum("nji,njk->ik", design, weighted_design)
        update = np.linalg.solve(information, -np.einsum("nji,nj->i", weighted_design, t))
        change = float(np.abs(update - solution).max())
        solution = update
        if change < _CONVERGED:
            break
    covariance = symmetric(np.linalg.inv(information))
    residuals = design @ solution + t
    return TipSolution(
        solution[:3],
        solution[3:],
        covariance[:3, :3],
        covariance[3:, 3:],
        covariance[:3, 3:],
        float(np.sqrt(np.mean(np.sum(np.square(residuals), axis=1)))),
        pose_covariances is None,
    )
