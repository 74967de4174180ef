"""Smooth ground-truth trajectories, pure functions of time.

A moving body follows a Lissajous curve in a horizontal plane and faces along its velocity,
like a person wearing an HMD walking a figure-of-eight, or keeps looking at a fixed point (a
head-mounted camera watching a target while its wearer walks). Pure functions of time, so any
process can evaluate the ground truth at a measurement's timestamp without sharing state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation


@dataclass(frozen=True)
class LissajousPath:
    """``x = cx + ax sin(2 pi fx t)``, ``y = cy + ay sin(2 pi fy t + phase)``, ``z = cz``.

    Units: metres, hertz, seconds. Without ``look_at`` the body's x axis points along its
    horizontal velocity. With ``look_at`` (a point in the parent frame, whose z axis is up) the
    body's z axis points at that point and its x axis stays horizontal, so a camera mounted with
    OpenCV's axes (z forward, y down) keeps the point in view.
    """

    centre: tuple[float, float, float] = (0.0, 0.0, 1.6)
    amplitude: tuple[float, float] = (1.0, 0.5)
    frequency: tuple[float, float] = (0.1, 0.2)
    phase: float = 0.0
    look_at: tuple[float, float, float] | None = None

    def pose(self, time_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Rotation quaternion (x, y, z, w) and translation of the body at ``time_s``."""
        (ax, ay), (fx, fy) = self.amplitude, self.frequency
        wx, wy = 2 * np.pi * fx, 2 * np.pi * fy
        position = np.array(
            [
                self.centre[0] + ax * np.sin(wx * time_s),
                self.centre[1] + ay * np.sin(wy * time_s + self.phase),
                self.centre[2],
            ]
        )
        if self.look_at is not None:
            return look_at_rotation(np.asarray(self.look_at, dtype=float) - position), position
        velocity = (ax * wx * np.cos(wx * time_s), ay * wy * np.cos(wy * time_s + self.phase))
        heading = np.arctan2(velocity[1], velocity[0])
        return Rotation.from_euler("z", heading).as_quat(), position


def look_at_rotation(forward: np.ndarray) -> np.ndarray:
    """Quaternion of a frame whose z axis points along ``forward`` and whose x axis is
    horizontal (perpendicular to the parent's z axis), so that its y axis points downwards."""
    z = forward / np.linalg.norm(forward)
    x = np.cross(z, (0.0, 0.0, 1.0))
    norm = np.linalg.norm(x)
    if norm < 1e-9:
        raise ValueError("look_at direction is vertical: the horizontal axis is undefined")
    x /= norm
    return Rotation.from_matrix(np.column_stack([x, np.cross(z, x), z])).as_quat()
