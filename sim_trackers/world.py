"""The simulated world: frames in a tree, moving or fixed, and the cameras' image planes.

Every frame but the root has a parent and a placement: the pose of the frame in its parent
(``x_parent = R x_frame + t``, ``docs/architecture.md``), either fixed or a function of time (a
trajectory). :meth:`World.pose` answers the ground truth between *any* two frames at any time
by composing placements up to the root and back down. Image planes are not rigid frames: an
image plane belongs to a camera frame and maps points of that frame to pixels through OpenCV's
camera model (pinhole ``K`` plus distortion, ``cv2.projectPoints``).

Everything is a pure function of the timestamp, so separate simulator processes built from the
same scenario agree on the ground truth without sharing state.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np

from ubitrack_agent.core import se3

IDENTITY = (np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3))

NEAR_PLANE_M = 0.01
"""Points closer to the camera than this (along its z axis) are not visible."""


class Placement(Protocol):
    """The pose of a frame in its parent as a function of time (seconds)."""

    def pose(self, time_s: float) -> tuple[np.ndarray, np.ndarray]: ...


@dataclass(frozen=True)
class FixedPlacement:
    """A placement that never changes: rotation ``(x, y, z, w)`` and translation in metres."""

    rotation: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    translation: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def pose(self, time_s: float) -> tuple[np.ndarray, np.ndarray]:
        return np.array(self.rotation, dtype=float), np.array(self.translation, dtype=float)


@dataclass(frozen=True)
class Frame:
    """A named coordinate frame; the root has neither parent nor placement."""

    name: str
    parent: str | None = None
    placement: Placement | None = None

    @property
    def fixed(self) -> bool:
        return self.parent is None or isinstance(self.placement, FixedPlacement)


@dataclass(frozen=True)
class ImagePlane:
    """The image plane of the camera frame ``camera``: intrinsics, distortion, image size.

    ``matrix`` is ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``; ``distortion`` holds OpenCV's
    coefficients ``(k1, k2, p1, p2[, k3 ...])``; ``image_size`` is ``(width, height)`` in px.
    """

    name: str
    camera: str
    matrix: np.ndarray
    distortion: np.ndarray
    image_size: tuple[int, int]

    def projection_matrix(self) -> np.ndarray:
        """The 3x4 projection ``K [I | 0]`` of the camera frame onto this image plane (the
        distortion-free part of the camera model)."""
        return np.hstack([self.matrix, np.zeros((3, 1))])

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel positions (N x 2) of ``points`` (N x 3, camera frame, metres) and a mask of
        those in view: in front of the camera and inside the image, with and without
        distortion (so that a point far outside the field of view that the distortion
        polynomial folds back into the image does not count as visible)."""
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        if not len(points):
            return np.zeros((0, 2)), np.zeros(0, dtype=bool)
        pixels, _ = cv2.projectPoints(
            points, np.zeros(3), np.zeros(3), self.matrix, self.distortion
        )
        pixels = pixels.reshape(-1, 2)
        in_front = points[:, 2] > NEAR_PLANE_M
        depth = np.where(in_front, points[:, 2], 1.0)
        pinhole = (points @ self.matrix.T)[:, :2] / depth[:, None]
        return pixels, in_front & self._inside(pixels) & self._inside(pinhole)

    def _inside(self, pixels: np.ndarray) -> np.ndarray:
        width, height = self.image_size
        return (
            (pixels[:, 0] >= 0)
            & (pixels[:, 0] < width)
            & (pixels[:, 1] >= 0)
            & (pixels[:, 1] < height)
        )


class WorldError(ValueError):
    """The frames do not form one tree, or a name is unknown."""


class World:
    """Frames in one tree plus image planes; answers ground truth at any time (ns)."""

    def __init__(self, frames: Iterable[Frame], image_planes: Iterable[ImagePlane] = ()) -> None:
        self.frames: dict[str, Frame] = {}
        for frame in frames:
            if frame.name in self.frames:
                raise WorldError(f"frame {frame.name!r} is defined twice")
            self.frames[frame.name] = frame
        self.image_planes: dict[str, ImagePlane] = {plane.name: plane for plane in image_planes}
        self._check_tree()
        for plane in self.image_planes.values():
            if plane.name in self.frames:
                raise WorldError(f"image plane {plane.name!r} has the name of a frame")
            if plane.camera not in self.frames:
                raise WorldError(
                    f"image plane {plane.name!r}: unknown camera frame {plane.camera!r}"
                )

    def _check_tree(self) -> None:
        roots = [name for name, frame in self.frames.items() if frame.parent is None]
        if len(roots) != 1:
            raise WorldError(f"the frames need exactly one root (a frame without parent): {roots}")
        for name, frame in self.frames.items():
            if frame.parent is not None and frame.parent not in self.frames:
                raise WorldError(f"frame {name!r}: unknown parent {frame.parent!r}")
            if (frame.parent is None) != (frame.placement is None):
                raise WorldError(f"frame {name!r}: a placement needs a parent and vice versa")
        for name in self.frames:
            seen = {name}
            for ancestor in self._ancestors(name):
                if ancestor in seen:
                    raise WorldError(
                        f"frame {name!r}: its parents form a cycle through {ancestor!r}"
                    )
                seen.add(ancestor)

    def _ancestors(self, name: str) -> Iterable[str]:
        parent = self.frames[name].parent
        seen = {name}
        while parent is not None and parent not in seen:
            yield parent
            seen.add(parent)
            parent = self.frames[parent].parent
        if parent is not None:
            yield parent

    def _frame(self, name: str) -> Frame:
        frame = self.frames.get(name)
        if frame is None:
            raise WorldError(f"unknown frame {name!r}; frames: {sorted(self.frames)}")
        return frame

    def _in_root(self, name: str, time_s: float) -> tuple[np.ndarray, np.ndarray]:
        frame = self._frame(name)
        pose = IDENTITY
        while frame.placement is not None:
            pose = se3.compose(*frame.placement.pose(time_s), *pose)
            frame = self.frames[frame.parent]
        return pose

    def pose(self, source: str, target: str, timestamp_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """Ground truth of ``target`` in ``source`` at ``timestamp_ns``: quaternion, metres."""
        time_s = timestamp_ns * 1e-9
        return se3.compose(
            *se3.invert(*self._in_root(source, time_s)), *self._in_root(target, time_s)
        )

    def is_static(self, source: str, target: str) -> bool:
        """Whether ``source -> target`` never changes: no moving frame between them."""
        up_source = [self._frame(source).name, *self._ancestors(source)]
        up_target = [self._frame(target).name, *self._ancestors(target)]
        common = next(name for name in up_source if name in up_target)
        path = up_source[: up_source.index(common)] + up_target[: up_target.index(common)]
        return all(self.frames[name].fixed for name in path)

    def project(
        self, image_plane: str, targets: Iterable[str], timestamp_ns: int
    ) -> dict[str, np.ndarray]:
        """Noise-free pixel positions of the origins of ``targets`` that are in view."""
        plane = self.image_planes.get(image_plane)
        if plane is None:
            raise WorldError(
                f"unknown image plane {image_plane!r}; known: {sorted(self.image_planes)}"
            )
        targets = list(targets)
        points = np.array([self.pose(plane.camera, name, timestamp_ns)[1] for name in targets])
        pixels, visible = plane.project(points)
        return {name: pixels[i] for i, name in enumerate(targets) if visible[i]}
