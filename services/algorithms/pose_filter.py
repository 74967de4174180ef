"""Asynchronous pose fusion: an error-state Kalman filter updated by each measurement as it
arrives, from any number of trackers at their own rates.

Model (constant velocity). State: orientation ``q``, position ``p``, world-frame angular
velocity ``omega`` and linear velocity ``v``; between measurements ``q(t + dt) = Exp(omega dt)
q(t)``, ``p(t + dt) = p(t) + v dt``, the velocities driven by white angular and linear
acceleration of spectral densities ``angular_noise`` (rad^2/s^3) and ``linear_noise``
(m^2/s^3) (the white-noise acceleration model, Bar-Shalom, Li, Kirubarajan, "Estimation with
Applications to Tracking and Navigation", 2001, section 6.2). Error state ``(dphi, dp,
domega, dv)`` with the multiplicative orientation error ``q = Exp(dphi) q_mean`` (Sola,
"Quaternion kinematics for the error-state Kalman filter", arXiv:1711.02508, 2017). A
measurement is a pose with its 6x6 left-perturbation covariance (the core's convention,
``T = Exp(xi) T_mean``, ``xi = (phi, rho)``), mapped to ``(dphi, dp)`` by ``dp = rho -
[t]x phi``.

How it is used, after Ubitrack's ``PoseKalmanFilter`` and Welch & Bishop's SCAAT ("SCAAT:
Incremental Tracking with Incomplete Information", SIGGRAPH 1997): every measurement updates
the filter as it arrives and the posterior at its time is the output (push in, push out); a
pose at any other time is predicted from the motion model (pull). In addition:

* **Out-of-order measurements** within ``window_ns`` of the newest are re-filtered: the filter
  keeps the posterior after each measurement of that window, goes back to the last one before
  the late measurement and applies it and the later measurements again in time order (the
  exact sequential result, as if it had arrived in order). Older ones are refused.
* **Innovation gating**: a measurement whose normalised innovation squared ``r^T S^-1 r``
  exceeds ``gate`` (the chi-square quantile of 6 degrees of freedom; 27.86 is 99.99 %) is
  refused and leaves the state unchanged (a PnP flip, 180 degrees about the optical axis
  away, never moves the output). ``restart_after`` refused measurements in a row restart the
  filter at the latest: the target really is elsewhere (or the filter started on an outlier).
* A measurement more than ``restart_ns`` after the newest (a tracker gap) restarts the
  filter, as the constant-velocity extrapolation over such a gap is meaningless.

:meth:`PoseKalmanFilter.estimate` answers a time within the kept window by predicting from
the posterior just before it (the filtered, not smoothed, estimate), and a later time by
extrapolation from the newest, at most ``max_ahead_ns`` ahead.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import Literal, NamedTuple

import numpy as np
from scipy.linalg.lapack import dposv

from ubitrack_agent.core import quaternions
from ubitrack_agent.core.errors import ExtrapolationError, NoDataError
from ubitrack_agent.core.measurements import check_timestamp
from ubitrack_agent.core.timeline import MAX_AHEAD_NS
from ubitrack_agent.core.uncertainty import skew
from ubitrack_agent.services.algorithms._checks import as_array, as_quaternions, positive
from ubitrack_agent.services.algorithms.estimate import PoseEstimate, symmetric
from ubitrack_agent.services.algorithms.tangent import RotationSpace

GATE_9999 = 27.856
"""Chi-square quantile of 6 degrees of freedom at 99.99 %: the default innovation gate."""

_EYE6 = np.eye(6)
_EYE12 = np.eye(12)
_VELOCITY_BLOCKS = (np.array([0, 1, 2, 3, 4, 5]), np.array([6, 7, 8, 9, 10, 11]))
"""The diagonals of the transition's blocks (phi, omega) and (p, v), as one index."""
_ROTATIONS = RotationSpace()

Outcome = Literal["updated", "late", "gated", "restarted", "too_old"]
"""What :meth:`PoseKalmanFilter.update` did with a measurement: ``updated`` (in time order),
``late`` (older than the newest: re-filtered from the kept history), ``gated`` (refused by the
innovation gate), ``restarted`` (the filter started again at it), ``too_old`` (older than the
kept window; nothing changed)."""


class _State(NamedTuple):
    """The filter's estimate at ``timestamp_ns``: orientation, (p, omega, v), 12x12 error
    covariance."""

    timestamp_ns: int
    rotation: np.ndarray
    vector: np.ndarray
    covariance: np.ndarray


class _Measurement(NamedTuple):
    timestamp_ns: int
    rotation: np.ndarray
    translation: np.ndarray
    noise: np.ndarray
    """6x6 covariance of (dphi, dp)."""


@dataclass(frozen=True)
class FilterSettings:
    """The tuning of a :class:`PoseKalmanFilter` (see the module docstring)."""

    angular_noise: float
    linear_noise: float
    initial_speed_std: float = 1.0
    """Standard deviation of each velocity component at a (re)start (rad/s and m/s)."""
    gate: float = GATE_9999
    restart_after: int = 5
    window_ns: int = 200_000_000
    restart_ns: int = 500_000_000
    max_ahead_ns: int = MAX_AHEAD_NS

    def __post_init__(self) -> None:
        for name in ("angular_noise", "linear_noise", "initial_speed_std", "gate"):
            positive(name, getattr(self, name))
        for name in ("restart_after", "window_ns", "restart_ns", "max_ahead_ns"):
            if not isinstance(getattr(self, name), int) or getattr(self, name) < 0:
                raise ValueError(f"{name}: expected a non-negative integer")


def _process_noise(angular: float, linear: float) -> tuple[np.ndarray, ...]:
    """``(A3, A2, A1)``: the process noise over a gap ``g`` is ``g^3/3 A3 + g^2/2 A2 + g A1``
    (white acceleration integrated twice, per axis ``[[g^3/3, g^2/2], [g^2/2, g]]`` times the
    density)."""
    terms = tuple(np.zeros((12, 12)) for _ in range(3))
    for density, (value, rate) in ((angular, (0, 6)), (linear, (3, 9))):
        for axis in range(3):
            a, b = value + axis, rate + axis
            terms[0][a, a] = terms[2][b, b] = density
            terms[1][a, b] = terms[1][b, a] = density
    return terms


def _checked_covariance(value: np.ndarray) -> np.ndarray:
    """A symmetric positive definite 6x6 covariance, checked at the cost of one Cholesky
    factorisation (a filter update is on the latency path), or ``ValueError``."""
    covariance = as_array("covariance", value, (6, 6))
    if np.abs(covariance - covariance.T).max() > 1e-9 * np.abs(covariance).max():
        raise ValueError("covariance: must be symmetric")
    try:
        np.linalg.cholesky(covariance)
    except np.linalg.LinAlgError:
        raise ValueError("covariance: not positive definite") from None
    return covariance


def _solve_positive_definite(matrix: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, int]:
    """``(matrix^-1 right, info)`` for a symmetric positive definite ``matrix`` by LAPACK's
    ``dposv`` (Cholesky), called directly: one call, where ``numpy.linalg.solve``'s wrapper
    (LU) runs a dozen Python-level checks on every filter update (issue 12, ``docs/
    performance.md``, "Fusion"). ``info`` is LAPACK's: non-zero when the factorisation
    fails."""
    _, solution, info = dposv(matrix, right)
    return solution, info


def _to_error(translation: np.ndarray) -> np.ndarray:
    """``M`` with ``(dphi, dp) = M (phi, rho)``: ``dp = rho - [t]x phi`` to first order."""
    matrix = _EYE6.copy()
    matrix[3:, :3] = -skew(translation)
    return matrix


def _to_left(translation: np.ndarray) -> np.ndarray:
    """The inverse of :func:`_to_error`: ``rho = dp + [t]x phi``."""
    matrix = _EYE6.copy()
    matrix[3:, :3] = skew(translation)
    return matrix


class PoseKalmanFilter:
    """Error-state Kalman filter fusing asynchronous pose measurements of one moving edge.

    :meth:`update` takes measurements in any order (see the module docstring for the model,
    the re-filtering of late measurements, the gate and the restarts); :meth:`estimate`
    answers the pose and its covariance at a given time, :meth:`predict` at any time.
    """

    def __init__(self, angular_noise: float, linear_noise: float, **tuning: float) -> None:
        self.settings = FilterSettings(angular_noise, linear_noise, **tuning)
        """The process noise densities and the rest of :class:`FilterSettings` (``tuning``)."""
        self._history: list[tuple[_Measurement, _State]] = []
        """The measurements of the kept window with the posterior after each, in time order."""
        self._gated_in_row = 0
        self._noise = np.stack(
            _process_noise(self.settings.angular_noise, self.settings.linear_noise)
        ).reshape(3, 144)
        """The three terms of the process noise, flat: one product gives it for a gap."""

    @property
    def timestamp_ns(self) -> int | None:
        """Time of the newest measurement used, ``None`` before the first."""
        return self._history[-1][1].timestamp_ns if self._history else None

    # -- model ------------------------------------------------------------------------------

    def _propagate(self, state: _State, timestamp_ns: int) -> _State:
        """The state moved to ``timestamp_ns`` by the motion model (also backwards)."""
        dt = (timestamp_ns - state.timestamp_ns) * 1e-9
        if dt == 0.0:
            return state
        # The means on floats (numpy calls cost a hop most: docs/performance.md, "Fusion").
        px, py, pz, wx, wy, wz, vx, vy, vz = state.vector.tolist()
        step = quaternions.from_rotvec((wx * dt, wy * dt, wz * dt))
        vector = np.array((px + dt * vx, py + dt * vy, pz + dt * vz, wx, wy, wz, vx, vy, vz))
        transition = _EYE12.copy()
        transition[:3, :3] = quaternions.to_matrix(step)
        transition[_VELOCITY_BLOCKS] = dt  # d(phi)/d(omega) and d(p)/d(v): dt I
        gap = abs(dt)
        noise = (np.array([gap**3 / 3, gap**2 / 2, gap]) @ self._noise).reshape(12, 12)
        covariance = transition @ state.covariance @ transition.T + noise
        rotation = quaternions.multiply(step, state.rotation)
        return _State(timestamp_ns, rotation, vector, covariance)

    def _start(self, measurement: _Measurement) -> _State:
        covariance = np.zeros((12, 12))
        covariance[:6, :6] = measurement.noise
        covariance[6:, 6:] = self.settings.initial_speed_std**2 * np.eye(6)
        vector = np.concatenate((measurement.translation, np.zeros(6)))
        return _State(measurement.timestamp_ns, measurement.rotation, vector, covariance)

    def _correct(self, prior: _State, measurement: _Measurement) -> _State | None:
        """The posterior after ``measurement`` at the prior's time; None if gated."""
        # On floats where the values are a few numbers (each numpy call costs 10-20 us on a
        # CPU woken for the sample: docs/performance.md, "Data path").
        reference = tuple(prior.rotation.tolist())
        phi = _ROTATIONS.log(measurement.rotation.tolist(), reference)
        mx, my, mz = measurement.translation.tolist()
        px, py, pz = prior.vector[:3].tolist()
        residual = np.array((*phi, mx - px, my - py, mz - pz))
        rows = np.empty((6, 13))  # [r | P H^T]: one solve with S for the NIS and the gain
        rows[:, 0] = residual
        rows[:, 1:] = prior.covariance[:6, :]
        solved, info = _solve_positive_definite(prior.covariance[:6, :6] + measurement.noise, rows)
        if info != 0:
            raise ValueError("the innovation covariance is not positive definite")
        if residual @ solved[:, 0] > self.settings.gate:
            return None
        gain = solved[:, 1:].T
        correction = gain @ residual
        keep = _EYE12.copy()
        keep[:, :6] -= gain
        covariance = keep @ prior.covariance @ keep.T + gain @ measurement.noise @ gain.T
        correction_values = correction.tolist()
        x, y, z, w = _ROTATIONS.exp(correction_values[:3], reference)
        norm = math.sqrt(x * x + y * y + z * z + w * w)
        rotation = np.array((x / norm, y / norm, z / norm, w / norm))
        vector = prior.vector + correction[3:]
        return _State(prior.timestamp_ns, rotation, vector, symmetric(covariance))

    # -- measurements -------------------------------------------------------------------------

    def update(
        self,
        timestamp_ns: int,
        rotation: np.ndarray,
        translation: np.ndarray,
        covariance: np.ndarray,
        validated: bool = False,
    ) -> Outcome:
        """Fuse one pose measurement (quaternion, translation, 6x6 left covariance) taken at
        ``timestamp_ns``; returns what was done with it (:data:`Outcome`). ``ValueError`` for
        invalid input. With ``validated`` the values are those of a measurement the codec has
        validated (``core.measurements``: a fusion worker's input), not checked again."""
        if validated:
            q, t, cov = rotation, translation, covariance
        else:
            q = as_quaternions("rotation", np.reshape(rotation, (1, -1)))[0]
            t = as_array("translation", translation, (3,))
            cov = _checked_covariance(covariance)
            timestamp_ns = check_timestamp("timestamp_ns", timestamp_ns)
        to_error = _to_error(t)
        measurement = _Measurement(timestamp_ns, q, t, to_error @ cov @ to_error.T)
        newest = self.timestamp_ns
        if newest is None or measurement.timestamp_ns - newest > self.settings.restart_ns:
            return self._restart(measurement)
        if measurement.timestamp_ns >= newest:
            prior = self._propagate(self._history[-1][1], measurement.timestamp_ns)
            posterior = self._correct(prior, measurement)
            if posterior is None:
                return self._refused(measurement)
            self._gated_in_row = 0
            self._history.append((measurement, posterior))
            self._forget(measurement.timestamp_ns)
            return "updated"
        return self._late(measurement)

    def _refused(self, measurement: _Measurement) -> Outcome:
        self._gated_in_row += 1
        if self._gated_in_row >= self.settings.restart_after:
            return self._restart(measurement)
        return "gated"

    def _restart(self, measurement: _Measurement) -> Outcome:
        self._gated_in_row = 0
        self._history = [(measurement, self._start(measurement))]
        return "restarted"

    def _late(self, measurement: _Measurement) -> Outcome:
        """Re-filter from the last posterior before ``measurement`` (see the module docstring)."""
        times = [kept.timestamp_ns for kept, _ in self._history]
        index = bisect.bisect_right(times, measurement.timestamp_ns)
        if index == 0:
            return "too_old"
        start = self._history[index - 1][1]
        posterior = self._correct(self._propagate(start, measurement.timestamp_ns), measurement)
        if posterior is None:
            return "gated"  # not counted towards a restart, which starts at the newest
        replayed = [(measurement, posterior)]
        for later, _ in self._history[index:]:
            prior = self._propagate(replayed[-1][1], later.timestamp_ns)
            after = self._correct(prior, later)
            if after is not None:  # gated now, in the light of the late measurement
                replayed.append((later, after))
        self._history[index:] = replayed
        return "late"

    def _forget(self, newest_ns: int) -> None:
        """Drop what lies beyond the window (always keeping the newest posterior)."""
        horizon = newest_ns - self.settings.window_ns
        drop = 0
        while drop < len(self._history) - 1 and self._history[drop][0].timestamp_ns < horizon:
            drop += 1
        del self._history[:drop]

    # -- output -------------------------------------------------------------------------------

    def estimate(self, timestamp_ns: int) -> PoseEstimate:
        """Pose and 6x6 left-perturbation covariance at ``timestamp_ns``: predicted from the
        posterior just before it, within the kept window and up to ``max_ahead_ns`` after the
        newest measurement. :class:`NoDataError` before the first measurement,
        :class:`ExtrapolationError` outside those bounds."""
        if not self._history:
            raise NoDataError("the filter has no measurement yet")
        oldest, newest = self._history[0][1].timestamp_ns, self._history[-1][1].timestamp_ns
        if not oldest <= timestamp_ns <= newest + self.settings.max_ahead_ns:
            raise ExtrapolationError(
                f"timestamp {timestamp_ns} outside the filter's window [{oldest}, {newest}] "
                f"and the {self.settings.max_ahead_ns / 1e6:g} ms it predicts ahead"
            )
        return self.predict(timestamp_ns)

    def predict(self, timestamp_ns: int) -> PoseEstimate:
        """Pose and 6x6 left-perturbation covariance at any ``timestamp_ns``, from the
        posterior just before it (or the oldest kept); :class:`NoDataError` before the first
        measurement. The state is unchanged."""
        if not self._history:
            raise NoDataError("predict: the filter has no measurement yet")
        state = self._history[-1][1]
        if timestamp_ns < state.timestamp_ns:  # else the newest, as after every update
            times = [kept.timestamp_ns for _, kept in self._history]
            state = self._history[max(bisect.bisect_right(times, timestamp_ns) - 1, 0)][1]
        state = self._propagate(state, timestamp_ns)
        back = _to_left(state.vector[:3])
        # Symmetric to round-off (a congruence of the symmetrised posterior): not symmetrised
        # again, as a result of core.poses is not.
        covariance = back @ state.covariance[:6, :6] @ back.T
        rotation = state.rotation if state.rotation[3] >= 0 else -state.rotation
        return PoseEstimate(rotation, state.vector[:3].copy(), covariance)
