"""Multi-tracker fusion: simultaneous pose estimates of one edge combined into one.

:func:`fuse_poses` - inverse-covariance (information) weighting on the manifold. Each estimate
``T_i`` with covariance ``Sigma_i`` is expressed as a left perturbation of a reference pose,
``xi_i = Log(T_i T_ref^-1)``; the information-weighted mean ``(sum W_i)^-1 sum W_i xi_i``
(``W_i = Sigma_i^-1``) moves the reference, ``T_ref <- Exp(xi) T_ref``, until the step
vanishes (Gauss-Newton on SE(3)). The fused covariance is ``(sum W_i)^-1``. Left perturbations
all live in frame A, so the covariances need no transport to first order. Reference:
Barfoot & Furgale, "Associating uncertainty with three-dimensional poses for use in
estimation problems", IEEE T-RO 30(3), 2014, section IV (pose fusion).

:class:`PoseKalmanFilter` - for trackers that measure at different times: an error-state
Kalman filter with a constant-velocity model, state (q, p, omega, v) (orientation, position,
world-frame angular and linear velocity) and error state (dphi, dp, domega, dv) with the
multiplicative orientation error ``q = Exp(dphi) q_mean``. Process noise: white angular and
linear acceleration of spectral densities ``angular_noise`` (rad^2/s^3) and ``linear_noise``
(m^2/s^3). References: Sola, "Quaternion kinematics for the error-state Kalman filter",
arXiv:1711.02508, 2017; Bar-Shalom, Li, Kirubarajan, "Estimation with Applications to Tracking
and Navigation", 2001, section 6.2 (white-noise acceleration model).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from services.algorithms._checks import (
    as_array,
    as_covariances,
    as_points,
    as_quaternions,
    positive,
    same_count,
)
from services.algorithms.estimate import (
    PoseEstimate,
    left_residuals,
    perturb_left,
    rigid,
    symmetric,
    to_estimate,
)
from ubitrack_agent.core.measurements import check_timestamp
from ubitrack_agent.core.uncertainty import skew

_CONVERGED = 1e-13


def fuse_poses(
    rotations: np.ndarray,
    translations: np.ndarray,
    covariances: np.ndarray,
    max_iterations: int = 20,
) -> PoseEstimate:
    """The information-weighted mean of M >= 1 pose estimates of the same edge.

    ``rotations`` M x 4 (x, y, z, w), ``translations`` M x 3, ``covariances`` M x 6 x 6
    (left perturbation, positive definite). Returns the fused pose and its covariance.
    """
    q = as_quaternions("rotations", rotations)
    t = as_points("translations", translations, 3, 1)
    count = same_count(rotations=q, translations=t)
    covs = as_covariances("covariances", covariances, count, 6)
    weights = np.linalg.inv(covs)
    information = weights.sum(axis=0)
    covariance = symmetric(np.linalg.inv(information))
    poses = rigid(q, t)
    reference = poses[int(np.argmin(np.trace(covs, axis1=1, axis2=2)))]
    for _ in range(max_iterations):
        xi = left_residuals(poses, reference)
        step = covariance @ np.einsum("mij,mj->i", weights, xi)
        reference = perturb_left(step, reference)
        if np.linalg.norm(step) < _CONVERGED:
            break
    return to_estimate(reference, covariance)


def _to_position_error(translation: np.ndarray) -> np.ndarray:
    """``M`` with ``(dphi, dp) = M (phi, rho)``: ``dp = rho - [t]x phi`` to first order."""
    matrix = np.eye(6)
    matrix[3:, :3] = -skew(translation)
    return matrix


class PoseKalmanFilter:
    """Error-state Kalman filter fusing asynchronous pose measurements of one moving edge.

    Feed measurements in time order with :meth:`update`; ask for the pose at any time with
    :meth:`predict` (extrapolated with the constant-velocity model, also backwards). See the
    module docstring for the model.
    """

    def __init__(
        self, angular_noise: float, linear_noise: float, initial_speed_std: float = 1.0
    ) -> None:
        self._angular_noise = positive("angular_noise", angular_noise)
        self._linear_noise = positive("linear_noise", linear_noise)
        self._initial_speed_var = positive("initial_speed_std", initial_speed_std) ** 2
        self._timestamp_ns: int | None = None
        self._rotation = Rotation.identity()
        self._state = np.zeros(9)  # position, angular velocity, linear velocity
        self._covariance = np.eye(12)

    @property
    def timestamp_ns(self) -> int | None:
        """Time of the last measurement, ``None`` before the first."""
        return self._timestamp_ns

    def _propagated(self, timestamp_ns: int) -> tuple[Rotation, np.ndarray, np.ndarray]:
        if self._timestamp_ns is None:
            raise ValueError("predict: the filter has no measurement yet")
        dt = (check_timestamp("timestamp_ns", timestamp_ns) - self._timestamp_ns) * 1e-9
        step = Rotation.from_rotvec(self._state[3:6] * dt)
        state = self._state.copy()
        state[:3] += dt * state[6:9]
        transition = np.eye(12)
        transition[:3, :3] = step.as_matrix()
        transition[:3, 6:9] = transition[3:6, 9:12] = dt * np.eye(3)
        gap = abs(dt)
        block = np.array([[gap**3 / 3, gap**2 / 2], [gap**2 / 2, gap]])
        noise = np.zeros((12, 12))
        for start, density in ((0, self._angular_noise), (3, self._linear_noise)):
            index = np.r_[start : start + 3, start + 6 : start + 9]
            noise[np.ix_(index, index)] = density * np.kron(block, np.eye(3))
        covariance = transition @ self._covariance @ transition.T + noise
        return step * self._rotation, state, symmetric(covariance)

    def predict(self, timestamp_ns: int) -> PoseEstimate:
        """Pose and 6x6 left-perturbation covariance at ``timestamp_ns`` (state unchanged)."""
        rotation, state, covariance = self._propagated(timestamp_ns)
        back = np.linalg.inv(_to_position_error(state[:3]))
        pose_covariance = back @ covariance[:6, :6] @ back.T
        return PoseEstimate(rotation.as_quat(canonical=True), state[:3], symmetric(pose_covariance))

    def update(
        self,
        timestamp_ns: int,
        rotation: np.ndarray,
        translation: np.ndarray,
        covariance: np.ndarray,
    ) -> None:
        """Fuse one pose measurement (quaternion, translation, 6x6 left covariance).

        Raises ``ValueError`` for invalid input or a timestamp older than the last update.
        """
        q = as_quaternions("rotation", np.reshape(rotation, (1, -1)))[0]
        t = as_array("translation", translation, (3,))
        cov = as_covariances("covariance", np.reshape(covariance, (1, 6, 6)), 1, 6)[0]
        to_error = _to_position_error(t)
        noise = to_error @ cov @ to_error.T
        timestamp_ns = check_timestamp("timestamp_ns", timestamp_ns)
        if self._timestamp_ns is None:
            self._start(timestamp_ns, q, t, noise)
            return
        if timestamp_ns < self._timestamp_ns:
            raise ValueError(
                f"timestamp_ns: {timestamp_ns} is older than the filter state "
                f"({self._timestamp_ns}); feed measurements in time order"
            )
        predicted, state, prior = self._propagated(timestamp_ns)
        measured = Rotation.from_quat(q)
        residual = np.concatenate(((measured * predicted.inv()).as_rotvec(), t - state[:3]))
        innovation = prior[:6, :6] + noise
        gain = np.linalg.solve(innovation, prior[:6, :]).T
        correction = gain @ residual
        keep = np.eye(12)
        keep[:, :6] -= gain
        self._covariance = symmetric(keep @ prior @ keep.T + gain @ noise @ gain.T)
        self._rotation = Rotation.from_rotvec(correction[:3]) * predicted
        self._state = state + correction[3:]
        self._timestamp_ns = timestamp_ns

    def _start(self, timestamp_ns: int, q: np.ndarray, t: np.ndarray, noise: np.ndarray) -> None:
        self._timestamp_ns = timestamp_ns
        self._rotation = Rotation.from_quat(q)
        self._state = np.concatenate((t, np.zeros(6)))
        self._covariance = np.zeros((12, 12))
        self._covariance[:6, :6] = noise
        self._covariance[6:, 6:] = self._initial_speed_var * np.eye(6)
