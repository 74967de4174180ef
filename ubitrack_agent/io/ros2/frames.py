"""Frame names between the SRG and ROS: one documented, reversible mapping.

SRG frame names are key chunks (``core.names``: letters, digits and ``_.-+:=%~^!``); ROS frame
ids follow ROS names (letters, digits and ``_``, tokens not starting with a digit, ``/``
between tokens, no leading ``/``: tf2 refuses one). ROS names have no ``.``, SRG names no
``/``, so:

* **SRG -> ROS** (``ubitrack ros2 publish``): each ``.`` becomes ``/`` (``robot1.base_link``
  -> ``robot1/base_link``, ``HT`` -> ``HT``); a name that is then no ROS name (``my-frame``,
  ``1st``) is refused, unless an explicit mapping names it.
* **ROS -> SRG** (``ubitrack ros2 subscribe``): one leading ``/`` is dropped (ROS 1 habit) and
  each ``/`` becomes ``.``; an id that is then no SRG name (spaces, non-ASCII) is refused.

Explicit mappings (``--frame SRG=ROS``) take precedence in both directions, and an optional
prefix puts every ROS frame under one SRG namespace (``--frame-prefix ros.``: ``base_link``
<-> ``ros.base_link``), so a robot's ``map`` cannot clash with a tracker's.
"""

from __future__ import annotations

import re
from collections.abc import Mapping

from ubitrack_agent.core.names import check_name

ROS_FRAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$")
MAX_ROS_FRAME_CHARS = 128


class FrameNameError(ValueError):
    """A frame name has no counterpart on the other side; the message says why."""


class FrameNames:
    """The mapping of the module docstring. O(1) per name."""

    def __init__(self, explicit: Mapping[str, str] | None = None, prefix: str = "") -> None:
        self.to_ros_map = dict(explicit or {})
        self.to_srg_map = {ros: srg for srg, ros in self.to_ros_map.items()}
        if len(self.to_srg_map) != len(self.to_ros_map):
            raise ValueError("two SRG frames are mapped to the same ROS frame")
        for srg, ros in self.to_ros_map.items():
            check_name(srg)
            if not ROS_FRAME.match(ros):
                raise ValueError(f"--frame {srg}={ros}: {ros!r} is no ROS frame id")
        if prefix:
            check_name(prefix)
        self.prefix = prefix

    def to_ros(self, srg: str) -> str:
        """The ROS frame id of SRG frame ``srg``; :class:`FrameNameError` if it has none."""
        if srg in self.to_ros_map:
            return self.to_ros_map[srg]
        name = srg
        if self.prefix:
            if not srg.startswith(self.prefix):
                raise FrameNameError(f"{srg!r} does not start with the prefix {self.prefix!r}")
            name = srg[len(self.prefix) :]
        ros = name.replace(".", "/")
        if not ROS_FRAME.match(ros):
            raise FrameNameError(
                f"{srg!r} is no ROS frame id as {ros!r} (letters, digits and _, tokens not "
                "starting with a digit; map it with --frame SRG=ROS)"
            )
        return ros

    def to_srg(self, ros: str) -> str:
        """The SRG frame of ROS frame id ``ros``; :class:`FrameNameError` if it has none."""
        if ros in self.to_srg_map:
            return self.to_srg_map[ros]
        if len(ros) > MAX_ROS_FRAME_CHARS:
            raise FrameNameError(f"ROS frame id of {len(ros)} characters")
        name = self.prefix + (ros[1:] if ros.startswith("/") else ros).replace("/", ".")
        try:
            return check_name(name)
        except ValueError as exc:
            raise FrameNameError(f"ROS frame {ros[:60]!r} has no SRG name: {exc}") from None
