"""Measurement types, wire codec and SE(3) maths; no zenoh, no networkx, no processes."""

from ubitrack_agent.core.codec import decode, encode, to_json
from ubitrack_agent.core.errors import (
    ExtrapolationError,
    MeasurementError,
    NoDataError,
    NoMotionModel,
)
from ubitrack_agent.core.measurements import (
    MEASUREMENT_TYPES,
    CameraIntrinsics,
    ErrorPose,
    Measurement,
    Pose,
    Position2D,
    Position3D,
    PositionList2D,
    PositionList3D,
    Projection,
    Rotation3D,
)

__all__ = [
    "MEASUREMENT_TYPES",
    "CameraIntrinsics",
    "ErrorPose",
    "ExtrapolationError",
    "Measurement",
    "MeasurementError",
    "NoDataError",
    "NoMotionModel",
    "Pose",
    "Position2D",
    "Position3D",
    "PositionList2D",
    "PositionList3D",
    "Projection",
    "Rotation3D",
    "decode",
    "encode",
    "to_json",
]
