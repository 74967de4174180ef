"""The client layer: the sensor and application APIs (:class:`~.provider.Provider`,
:class:`~.application.Relation`) and real sources and sinks, with no simulator code: the sensor
adapter base (:mod:`.adapter`), the A.R.T. DTrack2 format and adapter (:mod:`.dtrack`), the
OptiTrack NatNet format and adapter (:mod:`.natnet`), the real camera's ArUco detection and
adapter (:mod:`.camera`, the one package here that loads OpenCV), ROS 2 tf over rmw_zenoh both
ways (:mod:`.ros2`, the ``ros2`` extra), MCAP recording and replay (:mod:`.recording`, the
``mcap`` extra) and the static-edges file of calibration results (:mod:`.static_edges`)."""

from ubitrack_agent.io.application import NoAgent, NotStatic, Relation, UnsolvedRelation
from ubitrack_agent.io.provider import EdgeAnnouncement, Provider

__all__ = ["EdgeAnnouncement", "NoAgent", "NotStatic", "Provider", "Relation", "UnsolvedRelation"]
