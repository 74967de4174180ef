"""Simulated camera: image positions of the marker points it sees, with pixel noise.

Each frame the camera takes its pose from the world, projects the scenario's ``camera.features``
through OpenCV's camera model of its image plane
(:meth:`ubitrack_agent.sim_trackers.world.ImagePlane.project`: field of view and points behind the
camera), hides each visible feature with probability ``camera.occlusion``, loses the whole frame
with probability ``camera.dropout``, and adds Gaussian pixel noise ``camera.noise_px`` per axis.
Each remaining feature ``F`` is one :class:`~ubitrack_agent.core.Position2D` on the 2D edge ``<image
plane> -> F`` (the paper's ``IP -> F1..F5``), all with the frame's timestamp and the covariance
``noise_px^2 I``.

The world moves on real time; a frame shows it at the real time it is taken and is stamped on
the simulated host's clock (:class:`~ubitrack_agent.net.clock.Clock`: ``--clock-offset-ms``
makes a camera whose host's clock is off).
"""

from __future__ import annotations

import numpy as np

from ubitrack_agent.core import Position2D
from ubitrack_agent.io.provider import EdgeAnnouncement
from ubitrack_agent.net.clock import Clock
from ubitrack_agent.sim_trackers.scenario import CameraSettings
from ubitrack_agent.sim_trackers.world import World

METRIC_SAMPLES = 20
"""Instants (one every 3 s) at which :func:`metric_sigma` measures the features' depth."""


def metric_sigma(world: World, settings: CameraSettings) -> float:
    """The metric error (m) the pixel noise induces at the features' median depth,
    ``noise_px * depth / f``: what the planner's cost model expects as a 2D edge's ``sigma``
    (``docs/planner.md``), rather than pixels."""
    plane = world.image_planes[settings.image_plane]
    depths = [
        world.pose(plane.camera, feature, k * 3_000_000_000)[1][2]
        for k in range(METRIC_SAMPLES)
        for feature in settings.features
    ]
    focal = 0.5 * (plane.matrix[0, 0] + plane.matrix[1, 1])
    return settings.noise_px * float(np.median(np.abs(depths))) / focal


def announcements(settings: CameraSettings, world: World) -> list[EdgeAnnouncement]:
    """One dynamic 2D edge ``<image plane> -> <feature>`` per feature, with the metric sigma."""
    sigma = metric_sigma(world, settings)
    return [
        EdgeAnnouncement(settings.image_plane, feature, "2D", rate=settings.rate, sigma=sigma)
        for feature in settings.features
    ]


class CameraSimulator:
    """Makes the 2D measurements the scenario's camera would take."""

    def __init__(
        self,
        world: World,
        settings: CameraSettings,
        rng: np.random.Generator,
        clock: Clock | None = None,
    ) -> None:
        self.world = world
        self.settings = settings
        self.rng = rng
        self.clock = clock or Clock()
        """The simulated host's clock, which stamps the measurements."""
        self.covariance = np.eye(2) * settings.noise_px**2

    def measure(self, timestamp_ns: int) -> dict[str, Position2D]:
        """Edge name -> measurement of every feature seen at the real time ``timestamp_ns``
        (stamped on :attr:`clock`)."""
        settings = self.settings
        if self.rng.random() < settings.dropout:
            return {}
        seen = self.world.project(settings.image_plane, settings.features, timestamp_ns)
        stamp = self.clock.reading(timestamp_ns)
        return {
            f"{settings.image_plane}_{feature}": Position2D(
                stamp,
                pixel + self.rng.normal(0.0, settings.noise_px, 2),
                self.covariance,
            )
            for feature, pixel in seen.items()
            if self.rng.random() >= settings.occlusion
        }
