"""The basic patterns, section 3.1: inversion and concatenation, with covariance propagation."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ubitrack_agent.core import (
    MEASUREMENT_TYPES,
    ErrorPose,
    Measurement,
    Pose,
    Position2D,
    Position3D,
    Projection,
    Rotation3D,
    quaternions,
    se3,
)
from ubitrack_agent.core.poses import (
    compose_pose_pairs,
    compose_poses,
    invert_pose,
    transform_position,
)
from ubitrack_agent.services.registry import Inputs, Port, Service, register

POSES = (Pose, ErrorPose)


@register
class Inversion(Service):
    """B->A from A->B, for 6D poses (covariance transported exactly) and 3D rotations."""

    NAME = "inversion"
    INPUTS = {"AB": Port((Pose, ErrorPose, Rotation3D))}
    OUTPUTS = ("BA",)

    def compute(self, values: Inputs, timestamp_ns: int) -> dict[str, Measurement]:
        value = values["AB"]
        if isinstance(value, Rotation3D):
            return {"BA": Rotation3D(timestamp_ns, quaternions.conjugate(value.rotation))}
        return {"BA": invert_pose(value)}


@register
class Concatenation(Service):
    """A->C from A->B (port ``AB``) and B->C (port ``BC``).

    Supported pairs: pose x pose -> pose, pose x position -> position, rotation x rotation ->
    rotation, projection x pose -> projection, projection x position -> image position.
    Covariances propagate to first order where the inputs carry them (6D, 3D).
    """

    NAME = "concatenation"
    INPUTS = {
        "AB": Port((Pose, ErrorPose, Rotation3D, Projection)),
        "BC": Port((Pose, ErrorPose, Position3D, Rotation3D)),
    }
    OUTPUTS = ("AC",)

    def compute(self, values: Inputs, timestamp_ns: int) -> dict[str, Measurement]:
        first, second = values["AB"], values["BC"]
        if isinstance(first, POSES) and isinstance(second, POSES):
            result: Measurement = compose_poses(first, second)
        elif isinstance(first, POSES) and isinstance(second, Position3D):
            result = transform_position(first, second)
        elif isinstance(first, Rotation3D) and isinstance(second, Rotation3D):
            result = Rotation3D(timestamp_ns, quaternions.multiply(first.rotation, second.rotation))
        elif isinstance(first, Projection) and isinstance(second, POSES):
            pose = se3.to_matrix(second.rotation, second.translation)
            result = Projection(timestamp_ns, first.matrix @ pose)
        elif isinstance(first, Projection) and isinstance(second, Position3D):
            x = first.matrix @ np.append(second.position, 1.0)
            if abs(x[2]) < 1e-12:
                raise ValueError("point projects to infinity")
            result = Position2D(timestamp_ns, x[:2] / x[2])
        else:
            raise ValueError(
                f"cannot concatenate {type(first).__name__} with {type(second).__name__}"
            )
        return {"AC": result}

    def compute_run(
        self, values: Sequence[Inputs], timestamps: Sequence[int]
    ) -> list[dict[str, Measurement]]:
        """Pose pairs by :func:`compose_pose_pairs` (a few numpy calls for the whole run);
        any other pair one instant at a time."""
        firsts, seconds = [v["AB"] for v in values], [v["BC"] for v in values]
        if all(isinstance(v, POSES) for v in (*firsts, *seconds)):
            return [{"AC": result} for result in compose_pose_pairs(firsts, seconds)]
        return [self.compute(v, t) for v, t in zip(values, timestamps, strict=True)]


@register
class Relay(Service):
    """Forwards a measured edge unchanged: serves a query whose answer is a measured edge on the
    query's stable relation key (the agent's only component that no template describes)."""

    NAME = "relay"
    INPUTS = {"in": Port(tuple(MEASUREMENT_TYPES.values()))}
    OUTPUTS = ("out",)

    def compute(self, values: Inputs, timestamp_ns: int) -> dict[str, Measurement]:
        return {"out": values["in"]}
