"""The result type of the pose algorithms and the SE(3) tangent-space maps they share.

A pose is the pose of B in A (``x_A = R x_B + t``) as a unit quaternion (x, y, z, w) and a
translation in metres; its covariance, where there is one, is 6x6 over the left perturbation
``T = Exp(xi) T_mean``, ``xi = (phi, rho)``, rotation first: the conventions of
:mod:`ubitrack_agent.core.measurements`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import RigidTransform, Rotation

from ubitrack_agent.core.measurements import ErrorPose, Pose
from ubitrack_agent.core.uncertainty import skew


class PoseEstimate(NamedTuple):
    """A pose of B in A with an optional 6x6 left-perturbation covariance."""

    rotation: np.ndarray
    """Unit quaternion (x, y, z, w), shape (4,)."""
    translation: np.ndarray
    """Translation in metres (or the caller's unit), shape (3,)."""
    covariance: np.ndarray | None = None
    """6x6 covariance of ``xi = (phi, rho)`` with ``T = Exp(xi) T_mean``, or ``None``."""

    def matrix(self) -> np.ndarray:
        """The rotation matrix (3x3)."""
        return Rotation.from_quat(self.rotation).as_matrix()

    def to_measurement(self, timestamp_ns: int) -> Pose | ErrorPose:
        """The core measurement: an :class:`ErrorPose` if there is a covariance, else a ``Pose``;
        a result of this package's maths, checked for shapes only (``Measurement.derived``:
        the encoder checks its numbers, the consumer validates it at level ``WORKER``)."""
        if self.covariance is None:
            return Pose.derived(
                timestamp_ns=timestamp_ns, rotation=self.rotation, translation=self.translation
            )
        return ErrorPose.derived(
            timestamp_ns=timestamp_ns,
            rotation=self.rotation,
            translation=self.translation,
            covariance=self.covariance,
        )


def from_rotation_matrix(
    rotation: np.ndarray, translation: np.ndarray, covariance: np.ndarray | None = None
) -> PoseEstimate:
    """A :class:`PoseEstimate` from a rotation matrix (sign of the quaternion: w >= 0)."""
    q = Rotation.from_matrix(rotation).as_quat(canonical=True)
    return PoseEstimate(q, np.asarray(translation, dtype=float).reshape(3), covariance)


def rigid(rotations: np.ndarray, translations: np.ndarray) -> RigidTransform:
    """scipy transforms of quaternions (..., 4) and translations (..., 3)."""
    return RigidTransform.from_components(translations, Rotation.from_quat(rotations))


def left_residuals(transforms: RigidTransform, reference: RigidTransform) -> np.ndarray:
    """``xi_i = Log(T_i T_ref^-1)``: each ``T_i`` as a left perturbation of ``reference``."""
    return np.atleast_2d((transforms * reference.inv()).as_exp_coords())


def nees(estimate: PoseEstimate, truth: PoseEstimate) -> float | None:
    """``xi^T P^-1 xi`` of the estimate's left error ``xi = Log(T T_true^-1)`` against its own
    covariance ``P``, or ``None`` without one: its mean is 6 when the covariance is honest
    (the normalised estimation error squared: Bar-Shalom, Li, Kirubarajan, *Estimation with
    Applications to Tracking and Navigation*, 2001, section 5.4)."""
    if estimate.covariance is None:
        return None
    error = left_residuals(
        rigid(estimate.rotation, estimate.translation), rigid(truth.rotation, truth.translation)
    )[0]
    return float(error @ np.linalg.solve(estimate.covariance, error))


def perturb_left(xi: np.ndarray, reference: RigidTransform) -> RigidTransform:
    """``Exp(xi) T_ref``."""
    return RigidTransform.from_exp_coords(xi) * reference


def to_estimate(transform: RigidTransform, covariance: np.ndarray | None) -> PoseEstimate:
    """A :class:`PoseEstimate` of a single scipy transform."""
    translation, rotation = transform.as_components()
    return PoseEstimate(rotation.as_quat(canonical=True), translation, covariance)


def point_jacobian(points: np.ndarray) -> np.ndarray:
    """``d(Exp(xi) y)/d xi`` at ``xi = 0`` for transformed points ``y`` (N x 3): ``[-[y]x, I]``.

    Returns N x 3 x 6.
    """
    identity = np.broadcast_to(np.eye(3), (len(points), 3, 3))
    return np.concatenate((-skew(points), identity), axis=-1)


def symmetric(matrix: np.ndarray) -> np.ndarray:
    """The symmetric part of a square matrix (removes round-off asymmetry)."""
    return 0.5 * (matrix + np.swapaxes(matrix, -1, -2))
