"""Calibration database: the static edges of a setup, served over zenoh as one provider.

As in the paper's figure 6, calibration results that do not change at run time (the camera's
projection ``C -> IP``, the camera-to-head-target calibration ``C -> HT``, the marker positions
``WT -> F1..F5`` on the world target, the augmentation's placement ``WT -> A``) come from a
database rather than a tracker. The values are the scenario's ground truth: 6D edges as
:class:`~ubitrack_agent.core.Pose`, 3D edges as :class:`~ubitrack_agent.core.Position3D`, an
image plane's ``3x4`` edge as the :class:`~ubitrack_agent.core.Projection` ``K [I | 0]`` and its
``intrinsics`` edge (named ``<camera>_<plane>_intrinsics``, so it can sit beside the 3x4 edge)
as :class:`~ubitrack_agent.core.CameraIntrinsics` with the distortion coefficients.

The values can also come from a static-edges file (real calibration results), read and written
by :mod:`ubitrack_agent.io.static_edges`, which describes the format.

The provider publishes each value once; its data keys keep answering queries with it
(:class:`ubitrack_agent.net.transport.LatestValuePublisher`), so consumers started later fetch it.
"""

from __future__ import annotations

from ubitrack_agent.core import CameraIntrinsics, Measurement, Pose, Position3D, Projection
from ubitrack_agent.io.static_edges import StaticEdge, static_announcement
from ubitrack_agent.sim_trackers.scenario import DatabaseEdge
from ubitrack_agent.sim_trackers.world import World


def _value(world: World, edge: DatabaseEdge, timestamp_ns: int) -> Measurement:
    if edge.type == "6D":
        return Pose(timestamp_ns, *world.pose(edge.source, edge.target, timestamp_ns))
    if edge.type == "3D":
        return Position3D(timestamp_ns, world.pose(edge.source, edge.target, timestamp_ns)[1])
    plane = world.image_planes[edge.target]
    if edge.type == "3x4":
        return Projection(timestamp_ns, plane.projection_matrix())
    return CameraIntrinsics(timestamp_ns, plane.matrix, plane.distortion, plane.image_size)


def static_edges(
    world: World, edges: tuple[DatabaseEdge, ...], timestamp_ns: int
) -> list[StaticEdge]:
    """The database's edges with their values from ``world`` (stamped ``timestamp_ns``)."""
    return [
        StaticEdge(
            static_announcement(edge.source, edge.target, edge.type),
            _value(world, edge, timestamp_ns),
        )
        for edge in edges
    ]
