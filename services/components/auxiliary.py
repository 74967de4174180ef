"""Auxiliary patterns: splitting a pose into its position and rotation parts."""

from __future__ import annotations

from ubitrack_agent.core import ErrorPose, Measurement, Pose, Position3D, Rotation3D
from ubitrack_agent.services.algorithms import split_pose
from ubitrack_agent.services.registry import Inputs, Port, Service, register


@register
class PoseSplit(Service):
    """A->B 6D into A->B 3D (position, with its covariance) and A->B 3R (rotation)."""

    NAME = "pose_split"
    INPUTS = {"AB": Port((Pose, ErrorPose))}
    OUTPUTS = ("position", "rotation")

    def compute(self, values: Inputs, timestamp_ns: int) -> dict[str, Measurement]:
        pose = values["AB"]
        q, t, _, cov_t = split_pose(
            pose.rotation, pose.translation, getattr(pose, "covariance", None)
        )
        return {
            "position": Position3D(timestamp_ns, t, cov_t),
            "rotation": Rotation3D(timestamp_ns, q),
        }
