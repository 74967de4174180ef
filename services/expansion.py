"""Time expansion of a pattern's correspondence (paper section 3.3, "Expansion in Time").

Under time expansion each edge of the correspondence set is a single edge "measured at
different points in time": the worker synchronises the pattern's inputs at each trigger as
usual, and a :class:`TimeAccumulator` keeps the correspondence values of those instants that
differ enough from the last kept one (a minimum motion, so a resting target does not fill the
history with copies of one measurement). Once the multiplicity's lower bound is reached the
service computes on the accumulated lists; every further distinct sample refines the result.
The history is bounded (``max_samples``, oldest dropped first).

Options (``time_expansion`` in the component specification, checked by
:func:`ubitrack_agent.net.spec.parse_time_expansion`), defaults from the service:

* ``min_motion`` - least change of a position or translation (its unit: m, or px for 2D);
* ``min_rotation_deg`` - least change of a rotation, degrees;
* ``max_samples`` - the history's bound.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from typing import Any

import numpy as np

from ubitrack_agent.core import (
    ErrorPose,
    Measurement,
    Pose,
    Position2D,
    Position3D,
    Rotation3D,
    quaternions,
    to_json,
)
from ubitrack_agent.net.progress import Progress
from ubitrack_agent.services.registry import Inputs, Service

DEFAULT_MAX_SAMPLES = 200


def motion(before: Measurement, after: Measurement) -> tuple[float, float]:
    """(translation change, rotation change in degrees) between two values of one edge."""
    translation, rotation = 0.0, 0.0
    if isinstance(before, Pose | ErrorPose) and isinstance(after, Pose | ErrorPose):
        translation = float(np.linalg.norm(after.translation - before.translation))
    if isinstance(before, Position3D | Position2D) and isinstance(after, type(before)):
        translation = float(np.linalg.norm(after.position - before.position))
    if isinstance(before, Pose | ErrorPose | Rotation3D):
        relative = quaternions.multiply(quaternions.conjugate(before.rotation), after.rotation)
        rotation = float(np.degrees(quaternions.angle(relative)))
    return translation, rotation


class TimeAccumulator:
    """Collects distinct correspondence samples of one time-expanded pattern instance.

    For an incremental service (``Service.INCREMENTAL``, a running estimator over every sample
    since the start) it keeps only the last distinct sample, to judge the next one's
    distinctness, and hands each new one on alone."""

    def __init__(self, service: Service, options: Mapping[str, float]) -> None:
        self.service = service
        self.min_motion = options.get("min_motion", service.TIME_MIN_MOTION)
        self.min_rotation_deg = options.get("min_rotation_deg", service.TIME_MIN_ROTATION_DEG)
        size = 1 if service.INCREMENTAL else int(options.get("max_samples", DEFAULT_MAX_SAMPLES))
        self.samples: deque[dict[str, Measurement]] = deque(maxlen=size)

    def __len__(self) -> int:
        return len(self.samples)

    def _distinct(self, sample: dict[str, Measurement]) -> bool:
        """Not the instant last kept, and (if thresholds are set) moved enough since it."""
        if not self.samples:
            return True
        last = self.samples[-1]
        if all(value.timestamp_ns == last[port].timestamp_ns for port, value in sample.items()):
            return False
        if not (self.min_motion or self.min_rotation_deg):
            return True
        for port, value in sample.items():
            translation, rotation = motion(last[port], value)
            if (self.min_motion and translation >= self.min_motion) or (
                self.min_rotation_deg and rotation >= self.min_rotation_deg
            ):
                return True
        return False

    def add(self, values: Inputs) -> bool:
        """Keep the correspondence values of one instant if they are distinct; True if kept."""
        sample = {port: values[port] for port in self.service.CORRESPONDENCE}
        if not self._distinct(sample):
            return False
        self.samples.append(sample)
        return True

    def ready(self) -> bool:
        """Enough samples for the service (an incremental one counts its own)."""
        needed = 1 if self.service.INCREMENTAL else self.service.min_correspondences()
        return len(self.samples) >= needed

    def expanded(self, values: Inputs) -> dict[str, Any]:
        """``values`` with each correspondence port replaced by its accumulated list (for an
        incremental service: the latest sample alone)."""
        ports = self.service.CORRESPONDENCE
        return {**values, **{port: [sample[port] for sample in self.samples] for port in ports}}


class BatchProgress:
    """Progress of a static result recomputed over the accumulated samples (a time-expanded
    batch estimate: hand-eye, tip calibration), in the form averaging reports it
    (``ubitrack_agent.net.progress``).

    The uncertainty is the result's own covariance: RMS translation error ``sqrt(trace)`` of
    its translation (or position) block, RMS rotation error of its rotation block. Converged
    when the correspondences reach the service's multiplicity, both errors are within the
    tolerances, and the result moved by less than them over the last ``window`` results (the
    rule of :mod:`ubitrack_agent.services.algorithms.static_estimate`, on results instead of
    samples). Without a covariance it never converges: nothing says how good the result is.
    """

    def __init__(
        self,
        translation_tolerance: float = 1e-3,
        rotation_tolerance: float = float(np.radians(0.1)),
        window: int = 10,
    ) -> None:
        self.translation_tolerance = translation_tolerance
        self.rotation_tolerance = rotation_tolerance
        self._recent: deque[Measurement] = deque(maxlen=window + 1)

    def update(self, result: Measurement, samples: int, timestamp_ns: int) -> Progress:
        """The progress after a new ``result`` computed from ``samples`` correspondences."""
        self._recent.append(result)
        covariance = getattr(result, "covariance", None)
        std_t = std_r = None
        if covariance is not None:
            covariance = np.asarray(covariance)
            if covariance.shape == (6, 6):
                std_r = float(np.sqrt(np.trace(covariance[:3, :3])))
                std_t = float(np.sqrt(np.trace(covariance[3:, 3:])))
            else:
                std_t = float(np.sqrt(np.trace(covariance)))
        moved = [motion(self._recent[0], later) for later in self._recent]
        stable = len(self._recent) == self._recent.maxlen and all(
            t < self.translation_tolerance and r < np.degrees(self.rotation_tolerance)
            for t, r in moved
        )
        precise = std_t is not None and std_t <= self.translation_tolerance
        precise = precise and (std_r is None or std_r <= self.rotation_tolerance)
        return Progress(
            instance="",
            status="converged" if precise and stable else "averaging",
            accepted=samples,
            rejected=0,
            timestamp_ns=timestamp_ns,
            std_translation=std_t,
            std_rotation=std_r,
            tolerance_translation=self.translation_tolerance,
            tolerance_rotation=self.rotation_tolerance,
            value=to_json(result),
        )
