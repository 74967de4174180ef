"""Measurements as Foxglove's ``foxglove.FrameTransform`` (protobuf), for viewers.

The schema is Foxglove's own, from ``foxglove-schemas-protobuf`` (the ``mcap`` extra): the
recording stores it as a protobuf ``FileDescriptorSet`` of ``foxglove/FrameTransform.proto`` and
its imports, as MCAP's protobuf profile asks, so any MCAP reader decodes the channel without
this package. An edge ``A -> B`` (the pose of B in A) becomes ``parent_frame_id`` A and
``child_frame_id`` B, the translation in metres and the rotation as the quaternion
``(x, y, z, w)``, stamped with the measurement's timestamp. A 3D position becomes a transform
without rotation; other types (2D features, camera matrices) have none. O(1) per sample.
"""

from __future__ import annotations

from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from google.protobuf.descriptor import FileDescriptor
from google.protobuf.descriptor_pb2 import FileDescriptorSet

from ubitrack_agent.core import ErrorPose, Measurement, Pose, Position3D

TRANSFORM_TYPES = (Pose, ErrorPose, Position3D)
"""The measurement types that have a frame transform."""


def transform_schema() -> bytes:
    """The ``FileDescriptorSet`` of ``foxglove.FrameTransform``, its imports first."""
    descriptors = FileDescriptorSet()
    seen: set[str] = set()

    def add(file: FileDescriptor) -> None:
        if file.name in seen:
            return
        seen.add(file.name)
        for dependency in file.dependencies:
            add(dependency)
        file.CopyToProto(descriptors.file.add())

    add(FrameTransform.DESCRIPTOR.file)
    return descriptors.SerializeToString()


def frame_transform(source: str, target: str, measurement: Measurement) -> bytes | None:
    """The serialised ``FrameTransform`` of ``measurement`` of edge ``source -> target``;
    ``None`` for a type that has none."""
    if not isinstance(measurement, TRANSFORM_TYPES):
        return None
    message = FrameTransform(parent_frame_id=source, child_frame_id=target)
    message.timestamp.FromNanoseconds(measurement.timestamp_ns)
    if isinstance(measurement, Position3D):
        x, y, z = measurement.position.tolist()
        message.rotation.w = 1.0
    else:
        x, y, z = measurement.translation.tolist()
        rx, ry, rz, rw = measurement.rotation.tolist()
        message.rotation.x, message.rotation.y = rx, ry
        message.rotation.z, message.rotation.w = rz, rw
    message.translation.x, message.translation.y, message.translation.z = x, y, z
    return message.SerializeToString()
