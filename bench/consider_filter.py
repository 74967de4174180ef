"""A Schmidt "consider" pose filter: the fusion filter of issue 29 told which part of each
input's covariance is static, tried offline by :mod:`bench.fusion_consistency_bench`.

Why: the live fusion (:class:`~ubitrack_agent.services.algorithms.PoseKalmanFilter`) treats
each input's whole covariance as white noise. Where an input carries a static error (a
calibration's, shared by every sample of a session) that is wrong twice over: averaging many
samples does not average it away, and it cancels in the innovations (the prediction carries
the same error), so a filter that adapts its process noise to its innovations becomes
over-confident (``docs/performance.md``, "Is the fused covariance honest?").

The model: a measurement from source ``s`` (an input of the fusion: the A.R.T. path, the camera
path) is ``z = x + b_s + w`` in the pose's left tangent space, ``w`` white with covariance
``W`` (the part of the input's covariance from its dynamic edges), ``b_s`` a constant with
covariance ``B_s`` (the part from its static edges, set at the source's first measurement: the
approximation here is that the static error, which the concatenation transports by the
current pose's adjoint, stays constant in the output's frame). The filter is the
constant-velocity error-state filter of ``services/algorithms/pose_filter.py`` with each
source's ``b_s`` appended to its state and *considered*, not estimated (the Schmidt-Kalman
filter: the gain's rows of the biases set to zero, the covariance updated in Joseph form,
which holds for any gain; Schmidt 1966; Simon, *Optimal State Estimation*, 2006, section
7.5; Brink, "Partial-update Schmidt-Kalman filter", J. Guidance, Control, and Dynamics 40(9),
2017). The state's covariance is then that of its whole error, the biases' share included,
and the innovations' covariance holds the cross terms that make the static error's
cancellation expected, so their NIS can tune the process noise (``adaptive``, as
:class:`bench.fusion_consistency_bench.InnovationMatched`; Bar-Shalom, Li, Kirubarajan 2001,
section 11.2).

A prototype for the bench: measurements in time order, no re-filtering of late ones, no
restarts; the live filter's other duties stay there.
"""

from __future__ import annotations

import math

import numpy as np

from ubitrack_agent.core import quaternions
from ubitrack_agent.services.algorithms.estimate import PoseEstimate, symmetric
from ubitrack_agent.services.algorithms.pose_filter import (
    _ROTATIONS,
    GATE_9999,
    _process_noise,
    _to_error,
    _to_left,
)


class ConsiderFilter:
    """Constant-velocity pose filter with one considered static error per source (module
    docstring). ``sources`` name the inputs; ``adaptive`` scales the angular and the linear
    process noise on line (gain ``gain`` in log space per update) so that the rotation and
    position parts of the innovations' NIS average 3."""

    def __init__(
        self,
        angular_noise: float,
        linear_noise: float,
        sources: tuple[str, ...],
        adaptive: bool = False,
        gain: float = 0.02,
        initial_speed_std: float = 1.0,
    ) -> None:
        self._terms = (
            np.stack(_process_noise(angular_noise, 0.0)).reshape(3, 144),
            np.stack(_process_noise(0.0, linear_noise)).reshape(3, 144),
        )
        self._log_scales = [0.0, 0.0]
        self._adaptive, self._gain = adaptive, gain
        self._speed_variance = initial_speed_std**2
        self._offsets = {source: 12 + 6 * i for i, source in enumerate(sources)}
        self._size = 12 + 6 * len(sources)
        self._seen: set[str] = set()
        self._time_ns: int | None = None
        self._rotation = np.array([0.0, 0.0, 0.0, 1.0])
        self._vector = np.zeros(9)  # position, angular velocity, linear velocity
        self._covariance = np.zeros((self._size, self._size))

    @property
    def scales(self) -> tuple[float, float]:
        """The angular and linear process noise's current factors."""
        return math.exp(self._log_scales[0]), math.exp(self._log_scales[1])

    def _propagated(self, timestamp_ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rotation, vector and covariance moved to ``timestamp_ns`` (the biases stay)."""
        assert self._time_ns is not None
        dt = (timestamp_ns - self._time_ns) * 1e-9
        omega, velocity = self._vector[3:6], self._vector[6:]
        step = quaternions.from_rotvec(tuple((omega * dt).tolist()))
        rotation = quaternions.multiply(step, self._rotation)
        vector = self._vector.copy()
        vector[:3] += dt * velocity
        transition = np.eye(self._size)
        transition[:3, :3] = quaternions.to_matrix(step)
        transition[np.arange(6), np.arange(6, 12)] = dt
        gap = abs(dt)
        weights = np.array([gap**3 / 3, gap**2 / 2, gap])
        noise = np.zeros((self._size, self._size))
        noise[:12, :12] = sum(
            math.exp(scale) * (weights @ term).reshape(12, 12)
            for scale, term in zip(self._log_scales, self._terms, strict=True)
        )
        covariance = transition @ self._covariance @ transition.T + noise
        return rotation, vector, covariance

    def update(
        self,
        timestamp_ns: int,
        rotation: np.ndarray,
        translation: np.ndarray,
        white: np.ndarray,
        static: np.ndarray,
        source: str,
    ) -> bool:
        """Fuse one measurement of ``source`` (left covariances: ``white``, the dynamic part;
        ``static``, the static part); False if the innovation gate refused it."""
        to_error = _to_error(translation)
        noise = to_error @ white @ to_error.T
        offset = self._offsets[source]
        bias = slice(offset, offset + 6)
        if self._time_ns is None:
            self._time_ns, self._rotation = timestamp_ns, np.asarray(rotation, float)
            self._vector = np.concatenate((translation, np.zeros(6)))
            self._covariance[6:12, 6:12] = self._speed_variance * np.eye(6)
            self._covariance[:6, :6] = noise + to_error @ static @ to_error.T
            self._covariance[:6, bias] = to_error @ static
            self._covariance[bias, :6] = self._covariance[:6, bias].T
            self._covariance[bias, bias] = static
            self._seen.add(source)
            return True
        if source not in self._seen:  # a new source's static error: independent of the state
            self._covariance[bias, :] = 0.0
            self._covariance[:, bias] = 0.0
            self._covariance[bias, bias] = static
            self._seen.add(source)
        prior_rotation, prior_vector, prior = self._propagated(timestamp_ns)
        reference = tuple(prior_rotation.tolist())
        phi = _ROTATIONS.log(np.asarray(rotation).tolist(), reference)
        residual = np.concatenate((phi, np.asarray(translation) - prior_vector[:3]))
        observe = np.zeros((6, self._size))
        observe[:, :6] = np.eye(6)
        observe[:, bias] = to_error  # the bias is in the left tangent space
        innovation = symmetric(observe @ prior @ observe.T + noise)
        solved = np.linalg.solve(innovation, np.column_stack((residual, observe @ prior)))
        if residual @ solved[:, 0] > GATE_9999:
            return False
        gain = solved[:, 1:].T
        gain[12:, :] = 0.0  # Schmidt: the biases are considered, never corrected
        keep = np.eye(self._size) - gain @ observe
        covariance = keep @ prior @ keep.T + gain @ noise @ gain.T
        correction = gain[:12] @ residual
        x, y, z, w = _ROTATIONS.exp(correction[:3].tolist(), reference)
        norm = math.sqrt(x * x + y * y + z * z + w * w)
        self._rotation = np.array((x, y, z, w)) / norm
        self._vector = prior_vector + correction[3:12]
        self._covariance = symmetric(covariance)
        self._time_ns = timestamp_ns
        if self._adaptive:
            for block, part in enumerate((slice(0, 3), slice(3, 6))):
                nis = residual[part] @ np.linalg.solve(innovation[part, part], residual[part])
                moved = self._log_scales[block] + self._gain * (nis / 3 - 1.0)
                self._log_scales[block] = min(max(moved, -12.0), 12.0)
        return True

    def estimate(self, timestamp_ns: int) -> PoseEstimate:
        """The pose at ``timestamp_ns`` (at or after the newest measurement) and the 6x6 left
        covariance of its whole error, the considered static errors' share included."""
        rotation, vector, covariance = self._propagated(timestamp_ns)
        back = _to_left(vector[:3])
        rotation = rotation if rotation[3] >= 0 else -rotation
        return PoseEstimate(rotation, vector[:3].copy(), back @ covariance[:6, :6] @ back.T)
