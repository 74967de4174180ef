"""Multi-tracker fusion (section 3.1.3): simultaneous estimates of one edge combined."""

from __future__ import annotations

import numpy as np

from services.algorithms import fuse_poses
from services.registry import Inputs, Port, Service, complete_correspondences, register
from ubitrack_agent.core import ErrorPose, Measurement, Pose, Position3D, Rotation3D


@register
class Fusion(Service):
    """Information-weighted fusion of simultaneous estimates of one edge (space expansion).

    6D estimates are fused on SE(3) (:func:`services.algorithms.fuse_poses`); 3D positions by
    inverse-covariance weighting; 3R rotations on SO(3) by the same iteration (as poses without
    translation). An estimate without covariance gets ``default_sigma`` (metres and radians) on
    every axis, so plain estimates (and rotations, which carry none) get equal weights. The
    planner fuses two or more estimates; at run time those available at the trigger's time are
    fused, so the output goes on while one tracker has lost the target.
    """

    NAME = "fusion"
    INPUTS = {"AB": Port((Pose, ErrorPose, Position3D, Rotation3D))}
    OUTPUTS = ("fused",)
    CORRESPONDENCE = ("AB",)
    MIN_CORRESPONDENCES = 2
    PARAMETERS = {"default_sigma": 1e-3}

    def compute(self, values: Inputs, timestamp_ns: int) -> dict[str, Measurement]:
        estimates = [row[0] for row in complete_correspondences(values, self.CORRESPONDENCE)]
        if not estimates:
            raise ValueError("no estimate available at this time")
        default = float(self.parameters["default_sigma"]) ** 2
        if all(isinstance(e, Position3D) for e in estimates):
            infos = [
                np.linalg.inv(e.covariance if e.covariance is not None else default * np.eye(3))
                for e in estimates
            ]
            covariance = np.linalg.inv(sum(infos))
            mean = covariance @ sum(i @ e.position for i, e in zip(infos, estimates, strict=True))
            return {"fused": Position3D(timestamp_ns, mean, 0.5 * (covariance + covariance.T))}
        if all(isinstance(e, Rotation3D) for e in estimates):
            fused = fuse_poses(
                np.array([e.rotation for e in estimates]),
                np.zeros((len(estimates), 3)),
                np.array([default * np.eye(6)] * len(estimates)),
            )
            return {"fused": Rotation3D(timestamp_ns, fused.rotation)}
        if not all(isinstance(e, Pose | ErrorPose) for e in estimates):
            kinds = sorted({type(e).__name__ for e in estimates})
            raise ValueError(f"cannot fuse estimates of different types: {', '.join(kinds)}")
        covariances = [
            e.covariance if isinstance(e, ErrorPose) else default * np.eye(6) for e in estimates
        ]
        fused = fuse_poses(
            np.array([e.rotation for e in estimates]),
            np.array([e.translation for e in estimates]),
            np.array(covariances),
        )
        return {"fused": fused.to_measurement(timestamp_ns)}
