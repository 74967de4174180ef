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
* **Static errors considered** (issue 29): a measurement may say which part of its covariance
  is static (``static``: the share of its static edges, a calibration's error, the same in
  every sample of its ``source``) and which input it came from. Each such source's static
  error is appended to the state as a constant and *considered*, never corrected (the
  Schmidt-Kalman filter: the gain's rows of those states zero, the covariance updated in
  Joseph form, which holds for any gain; Schmidt 1966; Simon, *Optimal State Estimation*,
  2006, section 7.5). The state's covariance is then that of its whole error: averaging many
  samples of one source does not average its static error away. The static error is taken as
  constant in the output's frame (a concatenation transports it by the current pose: an
  approximation for slow changes of that pose). State size ``12 + 6 S`` for ``S`` such
  sources; an update costs ``O((12 + 6 S)^3)``, the filter without them ``O(12^3)``.
* **Process noise matched to the innovations** (``adaptive``): the angular and the linear
  density are each scaled on line (in log space, ``adaptation_gain`` per update) until the
  normalised innovations squared of the rotation and of the position average 3, their
  expectation (Bar-Shalom et al. 2001, section 11.2, adjustable level process noise). Only
  honest with the static errors considered: a static error common to a source's samples
  cancels in its innovations, and a filter adapting to them alone grows over-confident
  (``docs/performance.md``, "Is the fused covariance honest?").

:meth:`PoseKalmanFilter.estimate` answers a time within the kept window by predicting from
the posterior just before it (the filtered, not smoothed, estimate), and a later time by
extrapolation from the newest, at most ``max_ahead_ns`` ahead.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Hashable
from dataclasses import dataclass
from typing import Any, Literal, NamedTuple

import numpy as np
from scipy.linalg.lapack import dposv

from ubitrack_agent.core import quaternions
from ubitrack_agent.core.errors import ExtrapolationError, MeasurementError, NoDataError
from ubitrack_agent.core.measurements import check_covariance, check_semidefinite, check_timestamp
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
    """6x6 covariance of (dphi, dp): the white part, where ``static`` is given."""
    static: np.ndarray | None = None
    """6x6 left covariance of the source's static error, or None (all white)."""
    source: int = -1
    """Index of the source's static error among the filter's considered states."""


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
    adaptive: bool = False
    """Scale the process noise on line to the innovations (see the module docstring)."""
    adaptation_gain: float = 0.02
    min_noise_scale: float = math.exp(-12.0)
    """The least factor ``adaptive`` may scale each process noise density by: inputs that claim
    more error than they have make the innovations small, and the filter would otherwise cut
    its noise until its lag behind the motion fills their claim."""
    max_sources: int = 8
    """Static errors considered at once: a new source beyond them takes the place of the one
    seen longest ago that no kept measurement came from (a flow rewired away; its rows and
    columns dropped, which leaves the rest's distribution exact). Bounds an update's cost,
    ``O((12 + 6 max_sources)^3)``, whatever a long session's rewires bring."""

    def __post_init__(self) -> None:
        for name in (
            "angular_noise",
            "linear_noise",
            "initial_speed_std",
            "gate",
            "adaptation_gain",
            "min_noise_scale",
        ):
            positive(name, getattr(self, name))
        for name in ("restart_after", "window_ns", "restart_ns", "max_ahead_ns", "max_sources"):
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


def _checked_covariance(value: np.ndarray, name: str = "covariance") -> np.ndarray:
    """A symmetric positive definite 6x6 covariance, checked at the cost of one Cholesky
    factorisation (a filter update is on the latency path), or ``ValueError``."""
    covariance = as_array(name, value, (6, 6))
    if np.abs(covariance - covariance.T).max() > 1e-9 * np.abs(covariance).max():
        raise ValueError(f"{name}: must be symmetric")
    try:
        np.linalg.cholesky(covariance)
    except np.linalg.LinAlgError:
        raise ValueError(f"{name}: not positive definite") from None
    return covariance


def _white_part(covariance: np.ndarray, static: np.ndarray) -> np.ndarray:
    """``covariance - static``, or ``ValueError`` unless ``static`` is a covariance (the core's
    check) no larger than the whole: the difference positive semi-definite (zero where every
    edge is static)."""
    check_covariance("static", static)
    white = covariance - static
    try:
        check_semidefinite("covariance - static", white)
    except MeasurementError as exc:
        raise ValueError(f"static: must be no larger than the covariance ({exc})") from None
    return white


def _block(source: int) -> slice:
    """The rows of a considered source's static error in the state."""
    return slice(12 + 6 * source, 18 + 6 * source)


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

    def __init__(self, angular_noise: float, linear_noise: float, **tuning: Any) -> None:
        self.settings = FilterSettings(angular_noise, linear_noise, **tuning)
        """The process noise densities and the rest of :class:`FilterSettings` (``tuning``)."""
        self._history: list[tuple[_Measurement, _State]] = []
        """The measurements of the kept window with the posterior after each, in time order."""
        self._gated_in_row = 0
        self._terms = (
            np.stack(_process_noise(self.settings.angular_noise, 0.0)).reshape(3, 144),
            np.stack(_process_noise(0.0, self.settings.linear_noise)).reshape(3, 144),
        )
        """The angular and the linear process noise, each as three flat terms."""
        self._log_scales = [0.0, 0.0]
        """The factors of the two (``adaptive``), in log space."""
        self._noise = self._terms[0] + self._terms[1]
        """The three terms of the process noise, flat: one product gives it for a gap."""
        self._sources: dict[Hashable, int] = {}
        """The sources whose static errors the state considers, by the index of their block."""
        self._statics: list[np.ndarray] = []
        """Each considered source's static covariance (left), as its first measurement said."""
        self._seen: list[int] = []
        """Each considered source's latest measurement time."""

    @property
    def noise_scales(self) -> tuple[float, float]:
        """The factors of the angular and the linear process noise (1 unless ``adaptive``)."""
        return math.exp(self._log_scales[0]), math.exp(self._log_scales[1])

    @property
    def timestamp_ns(self) -> int | None:
        """Time of the newest measurement used, ``None`` before the first."""
        return self._history[-1][1].timestamp_ns if self._history else None

    # -- model ------------------------------------------------------------------------------

    def _propagate(self, state: _State, timestamp_ns: int) -> _State:
        """The state moved to ``timestamp_ns`` by the motion model (also backwards); the
        considered static errors stay, their cross-covariances move with the state."""
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
        if len(state.covariance) == 12:
            covariance = transition @ state.covariance @ transition.T + noise
        else:
            covariance = state.covariance.copy()
            covariance[:12, :12] = transition @ state.covariance[:12, :12] @ transition.T + noise
            covariance[:12, 12:] = transition @ state.covariance[:12, 12:]
            covariance[12:, :12] = covariance[:12, 12:].T
        rotation = quaternions.multiply(step, state.rotation)
        return _State(timestamp_ns, rotation, vector, covariance)

    def _start(self, measurement: _Measurement) -> _State:
        covariance = np.zeros((12, 12))
        covariance[:6, :6] = measurement.noise
        covariance[6:, 6:] = self.settings.initial_speed_std**2 * np.eye(6)
        covariance = self._considering(covariance)
        if measurement.static is not None:  # its static error is in the start's error
            block = _block(measurement.source)
            to_error = _to_error(measurement.translation)
            covariance[:6, :6] += to_error @ measurement.static @ to_error.T
            covariance[:6, block] = to_error @ measurement.static
            covariance[block, :6] = covariance[:6, block].T
        vector = np.concatenate((measurement.translation, np.zeros(6)))
        return _State(measurement.timestamp_ns, measurement.rotation, vector, covariance)

    def _considering(self, covariance: np.ndarray) -> np.ndarray:
        """``covariance`` with a block for each considered source it lacks: that source's
        static covariance, independent of the rest (its error came with its first sample)."""
        have = (len(covariance) - 12) // 6
        if have == len(self._statics):
            return covariance
        size = 12 + 6 * len(self._statics)
        grown = np.zeros((size, size))
        grown[: len(covariance), : len(covariance)] = covariance
        for index in range(have, len(self._statics)):
            grown[_block(index), _block(index)] = self._statics[index]
        return grown

    def _correct(
        self, prior: _State, measurement: _Measurement, replayed: bool = False
    ) -> _State | None:
        """The posterior after ``measurement`` at the prior's time; None if gated.
        ``replayed``: a measurement applied again after a late one (``adaptive`` learns from
        each measurement once)."""
        if self._sources or self.settings.adaptive:
            return self._correct_considering(prior, measurement, adapt=not replayed)
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

    def _correct_considering(
        self, prior: _State, measurement: _Measurement, adapt: bool
    ) -> _State | None:
        """:meth:`_correct` with the considered static errors (the Schmidt-Kalman update: the
        gain's rows of the static errors zero, the covariance in Joseph form), and, when
        ``adaptive`` and ``adapt``, the process noise scaled to the innovation (module
        docstring)."""
        covariance = self._considering(prior.covariance)
        size = len(covariance)
        observe = np.zeros((6, size))
        observe[:, :6] = _EYE6
        if measurement.static is not None:  # the static error is in the left tangent space
            observe[:, _block(measurement.source)] = _to_error(measurement.translation)
        reference = tuple(prior.rotation.tolist())
        phi = _ROTATIONS.log(measurement.rotation.tolist(), reference)
        residual = np.concatenate((phi, measurement.translation - prior.vector[:3]))
        crossed = covariance @ observe.T
        innovation = symmetric(observe @ crossed + measurement.noise)
        solved, info = _solve_positive_definite(innovation, np.column_stack((residual, crossed.T)))
        if info != 0:
            raise ValueError("the innovation covariance is not positive definite")
        if residual @ solved[:, 0] > self.settings.gate:
            return None
        gain = solved[:, 1:].T
        gain[12:] = 0.0  # Schmidt: the static errors are considered, never corrected
        keep = np.eye(size) - gain @ observe
        covariance = keep @ covariance @ keep.T + gain @ measurement.noise @ gain.T
        correction = gain[:12] @ residual
        x, y, z, w = _ROTATIONS.exp(correction[:3].tolist(), reference)
        norm = math.sqrt(x * x + y * y + z * z + w * w)
        rotation = np.array((x / norm, y / norm, z / norm, w / norm))
        if self.settings.adaptive and adapt:
            self._adapt(residual, innovation)
        return _State(
            prior.timestamp_ns, rotation, prior.vector + correction[3:], symmetric(covariance)
        )

    def _adapt(self, residual: np.ndarray, innovation: np.ndarray) -> None:
        """Move the angular and the linear noise's factors towards an NIS of 3 for the
        rotation and the position part of the innovation (bounded to ``min_noise_scale`` ..
        e^12)."""
        least = math.log(self.settings.min_noise_scale)
        for index, part in enumerate((slice(0, 3), slice(3, 6))):
            nis = residual[part] @ np.linalg.solve(innovation[part, part], residual[part])
            moved = self._log_scales[index] + self.settings.adaptation_gain * (nis / 3.0 - 1.0)
            self._log_scales[index] = min(max(moved, least), 12.0)
        self._noise = (
            math.exp(self._log_scales[0]) * self._terms[0]
            + math.exp(self._log_scales[1]) * self._terms[1]
        )

    # -- measurements -------------------------------------------------------------------------

    def update(
        self,
        timestamp_ns: int,
        rotation: np.ndarray,
        translation: np.ndarray,
        covariance: np.ndarray,
        validated: bool = False,
        static: np.ndarray | None = None,
        source: Hashable = None,
    ) -> Outcome:
        """Fuse one pose measurement (quaternion, translation, 6x6 left covariance) taken at
        ``timestamp_ns``; returns what was done with it (:data:`Outcome`). ``ValueError`` for
        invalid input. With ``validated`` the values are those of a measurement the codec has
        validated (``core.measurements``: a fusion worker's input), not checked again.
        ``static``: the part of ``covariance`` that is the static error of ``source`` (the
        input it came from), considered (module docstring); ``covariance - static`` must be
        positive semi-definite."""
        if validated:
            q, t, cov = rotation, translation, covariance
        else:
            q = as_quaternions("rotation", np.reshape(rotation, (1, -1)))[0]
            t = as_array("translation", translation, (3,))
            cov = _checked_covariance(covariance)
            timestamp_ns = check_timestamp("timestamp_ns", timestamp_ns)
        to_error = _to_error(t)
        if static is None:
            measurement = _Measurement(timestamp_ns, q, t, to_error @ cov @ to_error.T)
        else:
            white = _white_part(cov, as_array("static", static, (6, 6)))
            index = self._considered(source, static)
            self._seen[index] = max(self._seen[index], timestamp_ns)
            noise = to_error @ white @ to_error.T
            measurement = _Measurement(timestamp_ns, q, t, noise, self._statics[index], index)
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

    def _considered(self, source: Hashable, static: np.ndarray) -> int:
        """The index of ``source``'s static error, appended (with ``static``) if new; while
        more than :attr:`FilterSettings.max_sources` are considered, the one seen longest ago
        that no kept measurement came from (nor this one) is dropped."""
        if source not in self._sources:
            self._sources[source] = len(self._statics)
            self._statics.append(np.array(static, dtype=float))
            self._seen.append(-1)
        if len(self._statics) > self.settings.max_sources:
            busy = {kept.source for kept, _ in self._history} | {self._sources[source]}
            idle = [i for i in range(len(self._statics)) if i not in busy]
            if idle:
                self._drop_source(min(idle, key=self._seen.__getitem__))
        return self._sources[source]

    def _drop_source(self, index: int) -> None:
        """Stop considering source ``index``, which no kept measurement came from: its rows
        and columns leave every kept posterior (marginalisation: the rest's distribution is
        unchanged) and the later sources move up one block."""
        self._sources = {name: i - (i > index) for name, i in self._sources.items() if i != index}
        del self._statics[index], self._seen[index]
        start, end = _block(index).start, _block(index).stop
        history = []
        for measurement, posterior in self._history:
            if measurement.source > index:
                measurement = measurement._replace(source=measurement.source - 1)
            size = len(posterior.covariance)
            if size > start:  # the block is there (a posterior grows when it is used)
                rows = np.r_[0:start, end:size]
                posterior = posterior._replace(covariance=posterior.covariance[np.ix_(rows, rows)])
            history.append((measurement, posterior))
        self._history = history

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
            after = self._correct(prior, later, replayed=True)
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
