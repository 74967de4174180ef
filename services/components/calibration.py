"""Tip (pivot) calibration of a tracked pointer (Ubitrack's ``TipCalibration`` pattern).

A tracker T follows the marker M of a pointer whose tip rests on a fixed pivot while the user
turns the pointer about it (Tuceryan et al., "Calibration requirements and procedures for a
monitor-based augmented reality system", IEEE TVCG 1(3), 1995). Time expansion of the single
input ``TM`` collects the marker's poses; :func:`ubitrack_agent.services.algorithms.tip_calibration`
gives the tip in the marker and the pivot in the tracker with their covariances.
"""

from __future__ import annotations

import numpy as np

from ubitrack_agent.core import ErrorPose, Measurement, Pose, Position3D
from ubitrack_agent.services.algorithms import tip_calibration
from ubitrack_agent.services.registry import (
    Inputs,
    Port,
    Service,
    complete_correspondences,
    register,
)


@register
class TipCalibration(Service):
    """The tip of a pointer in its marker (``MP``) and the pivot in the tracker (``TP``), as
    ``Position3D`` with covariance, from the marker's poses in the tracker (``TM``).

    The samples' covariances weight the least squares when every sample has one
    (``ErrorPose``); otherwise the noise is estimated from the residuals, which needs many
    samples to be trustworthy: ``min_samples`` (30; at 10 the covariance comes out about 25 %
    small, ``docs/algorithms.md``). Kept samples differ by :attr:`TIME_MIN_ROTATION_DEG`.
    Rotations about a single axis leave the tip undetermined along it: below ``min_spread_deg``
    of rotation about the other axes the computation fails (``ValueError``) and waits for more
    samples.
    """

    NAME = "tip_calibration"
    INPUTS = {"TM": Port((Pose, ErrorPose))}
    OUTPUTS = ("MP", "TP")
    CORRESPONDENCE = ("TM",)
    MIN_CORRESPONDENCES = 3
    TIME_MIN_ROTATION_DEG = 2.0
    """A new sample is kept once the pointer has turned 2 degrees since the last kept one: far
    above tracker noise (about 0.1 degrees), and at a pivoting speed of 30 degrees per second
    about 15 samples per second, so the 200 kept (``ubitrack_agent.services.expansion``) span about
    13 s."""
    PARAMETERS = {"min_samples": 30, "min_spread_deg": 2.0}

    def min_correspondences(self) -> int:
        return max(self.MIN_CORRESPONDENCES, int(self.parameters["min_samples"]))

    def compute(self, values: Inputs, timestamp_ns: int) -> dict[str, Measurement]:
        rows = complete_correspondences(values, self.CORRESPONDENCE)
        if len(rows) < self.min_correspondences():
            raise ValueError(f"{len(rows)} poses, need {self.min_correspondences()}")
        poses = [pose for (pose,) in rows]
        covariances = None
        if all(isinstance(pose, ErrorPose) for pose in poses):
            covariances = np.array([pose.covariance for pose in poses])
        solution = tip_calibration(
            np.array([pose.rotation for pose in poses]),
            np.array([pose.translation for pose in poses]),
            covariances,
            min_spread_deg=float(self.parameters["min_spread_deg"]),
        )
        return {
            "MP": Position3D(timestamp_ns, solution.tip_in_marker, solution.tip_covariance),
            "TP": Position3D(timestamp_ns, solution.pivot_in_tracker, solution.pivot_covariance),
        }
