"""The camera's intrinsics, read from the ``intrinsics`` edge of a static-edges file
(:mod:`ubitrack_agent.io.static_edges`): the same file a calibration store or the database
serves, and the one ``ubitrack intrinsics`` writes (:mod:`.charuco`)."""

from __future__ import annotations

import os
import time

from ubitrack_agent.core import CameraIntrinsics
from ubitrack_agent.io.static_edges import StaticEdgesError, read_static_edges


def read_intrinsics(
    path: str | os.PathLike[str], camera: str, image_plane: str
) -> CameraIntrinsics:
    """The value of the ``intrinsics`` edge ``camera -> image_plane`` in the static-edges file
    ``path``; :class:`StaticEdgesError` if the file is invalid or holds no such edge."""
    _, edges = read_static_edges(path, time.time_ns())
    for edge in edges:
        ends = (edge.announcement.source, edge.announcement.target)
        if isinstance(edge.value, CameraIntrinsics) and ends == (camera, image_plane):
            return edge.value
    found = [f"{e.announcement.source}->{e.announcement.target}" for e in edges]
    raise StaticEdgesError(
        f"{path}: no intrinsics edge {camera}->{image_plane} (edges: {found or 'none'})"
    )
