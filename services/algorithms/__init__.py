"""Pure pattern algorithms: arrays in, arrays out (no zenoh, no processes, no state but objects').

Conventions, common to every function here:

* A **pose** is the pose of B in A, mapping ``x_B`` to ``x_A = R x_B + t``, returned as a
  :class:`~ubitrack_agent.services.algorithms.estimate.PoseEstimate` ``(rotation, translation,
  covariance)``: a unit quaternion (x, y, z, w), a translation (the unit of the input points,
  normally metres) and an optional 6x6 covariance over the left perturbation ``T = Exp(xi) T_mean``,
  ``xi = (phi, rho)``, rotation first (the core's convention,
  :mod:`ubitrack_agent.core.measurements`). ``PoseEstimate.to_measurement(timestamp_ns)``
  gives the core ``Pose``/``ErrorPose``.
* Pose inputs are arrays of quaternions (N x 4, x, y, z, w) and translations (N x 3).
* Points are N x 3 (3D) or N x 2 (pixels); cameras are a 3x3 intrinsic matrix plus OpenCV
  distortion coefficients; a projection is a 3x4 matrix ``P = K [R | t]``.
* Every bad input (wrong shape, too few points, NaN, degenerate geometry such as collinear
  points) raises ``ValueError`` with a message naming the argument.

Modules: :mod:`.absolute_orientation` (3D-3D), :mod:`.pnp` (2D-3D pose), :mod:`.dlt`
(projective calibration), :mod:`.triangulation`, :mod:`.hand_eye`, :mod:`.tip_calibration`
(pivot calibration), :mod:`.fusion` (inverse-covariance fusion), :mod:`.pose_filter` (an
error-state Kalman filter fusing asynchronous pose measurements as they arrive),
:mod:`.averaging`, :mod:`.static_estimate` (incremental, robust estimate of a static relation
from a stream, with convergence and motion checks; one object per stream, the only stateful
algorithm besides the Kalman filter), :mod:`.tangent` (left-perturbation log/exp of poses,
positions, rotations), :mod:`.auxiliary`.
"""

from ubitrack_agent.services.algorithms.absolute_orientation import absolute_orientation
from ubitrack_agent.services.algorithms.auxiliary import (
    compose_projection,
    decompose_projection,
    split_pose,
)
from ubitrack_agent.services.algorithms.averaging import average_poses, average_positions
from ubitrack_agent.services.algorithms.dlt import projection_dlt
from ubitrack_agent.services.algorithms.estimate import PoseEstimate
from ubitrack_agent.services.algorithms.fusion import fuse_poses
from ubitrack_agent.services.algorithms.hand_eye import (
    HandEyeSolution,
    hand_eye_calibration,
    hand_eye_daniilidis,
    hand_eye_park_martin,
)
from ubitrack_agent.services.algorithms.pnp import solve_pnp, solve_pnp_ransac
from ubitrack_agent.services.algorithms.pose_filter import FilterSettings, PoseKalmanFilter
from ubitrack_agent.services.algorithms.static_estimate import (
    Motion,
    StaticEstimator,
    StaticState,
    Status,
)
from ubitrack_agent.services.algorithms.tip_calibration import TipSolution, tip_calibration
from ubitrack_agent.services.algorithms.triangulation import Triangulation, triangulate_points

__all__ = [
    "FilterSettings",
    "HandEyeSolution",
    "Motion",
    "PoseEstimate",
    "PoseKalmanFilter",
    "StaticEstimator",
    "StaticState",
    "Status",
    "TipSolution",
    "Triangulation",
    "absolute_orientation",
    "average_poses",
    "average_positions",
    "compose_projection",
    "decompose_projection",
    "fuse_poses",
    "hand_eye_calibration",
    "hand_eye_daniilidis",
    "hand_eye_park_martin",
    "projection_dlt",
    "solve_pnp",
    "solve_pnp_ransac",
    "split_pose",
    "tip_calibration",
    "triangulate_points",
]
