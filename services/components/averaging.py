"""Averaging: a static relationship estimated over time from a dynamic estimate of it.

The time expansion of a static edge (paper sections 3.3 and 4.2: "direct computation" of a
calibration, a per-frame estimate composed of measured edges, integrated over time). Each
sample enters :class:`ubitrack_agent.services.algorithms.StaticEstimator` as it arrives: every
accepted sample since the flow started counts (information form), outliers such as PnP flips are
gated out, the covariance is checked against the samples' spread, and the estimate reports its
progress (``ubitrack_agent.net.progress``): converged by the estimator's rule, or not static when
the samples move more than their noise explains, in which case nothing is published.

The estimator counts samples; errors are correlated over time. Its motion check compares the
mean of a window of recent samples with the earlier ones, so the window is set to
``MOTION_WINDOW_S`` of samples at the input's rate, measured over the robust start's samples
(which the estimator would hold back anyway): at the live figure-1 flow's 90 Hz a window of 30
samples spans a third of a second, shorter than the stretches over which PnP's error follows
the viewing geometry, and the check fired on a static relation (recorded streams:
``bench/calibration_flows_bench.py``, ``docs/performance.md``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from ubitrack_agent.core import ErrorPose, Measurement, Pose, Position3D, Rotation3D, to_json
from ubitrack_agent.net.progress import Progress
from ubitrack_agent.services.algorithms import StaticEstimator, StaticState, Status
from ubitrack_agent.services.algorithms.static_estimate import (
    DEFAULT_INIT_SAMPLES,
    DEFAULT_MOTION_WINDOW,
)
from ubitrack_agent.services.registry import Inputs, Port, Service, register

MOTION_WINDOW_S = 1.0
"""The motion check's window, seconds (never fewer samples than the estimator's default)."""

MAX_MOTION_WINDOW = 1000
"""The longest motion window, samples (1 s at 1 kHz)."""

_KINDS: dict[type[Measurement], str] = {
    Pose: "pose",
    ErrorPose: "pose",
    Position3D: "position",
    Rotation3D: "rotation",
}


def static_estimator(
    kind: str, parameters: Mapping[str, Any], start: Sequence[Measurement]
) -> StaticEstimator:
    """The estimator the averaging service runs with ``parameters`` (its ``PARAMETERS``
    completed by the template's), its motion window set from the robust start's samples."""
    return StaticEstimator(
        kind,
        translation_tolerance=float(parameters["translation_tolerance"]),
        rotation_tolerance=math.radians(float(parameters["rotation_tolerance_deg"])),
        min_samples=int(parameters["min_samples"]),
        motion_window=motion_window(start),
    )


@register
class Averaging(Service):
    """The static estimate of edge A->B from its dynamic samples (time expansion): a robust,
    information-form mean with an honest covariance, a convergence rule and a motion check
    (:mod:`ubitrack_agent.services.algorithms.static_estimate`). Parameters: the tolerances at which
    the estimate counts as converged (``translation_tolerance`` in metres,
    ``rotation_tolerance_deg``) and the least number of accepted samples (``min_samples``)."""

    NAME = "averaging"
    INPUTS = {"AB": Port((Pose, ErrorPose, Position3D, Rotation3D))}
    OUTPUTS = ("mean",)
    CORRESPONDENCE = ("AB",)
    MIN_CORRESPONDENCES = 2
    INCREMENTAL = True
    PARAMETERS = {"min_samples": 50, "translation_tolerance": 5e-4, "rotation_tolerance_deg": 0.1}

    def __init__(self, parameters: Inputs) -> None:
        super().__init__(parameters)
        self._estimator: StaticEstimator | None = None
        self._kind: str | None = None
        self._start: list[Measurement] = []
        self._state: StaticState | None = None
        self._timestamp_ns = 0

    def min_correspondences(self) -> int:
        """Samples the estimator's robust start needs before its first estimate."""
        return DEFAULT_INIT_SAMPLES

    def _feed(self, sample: Measurement) -> None:
        """Hold the robust start's samples until there are enough to measure the rate, then
        start the estimator with a motion window of ``MOTION_WINDOW_S``; feed the rest."""
        kind = _KINDS[type(sample)]
        if self._kind is None:
            self._kind = kind
        elif kind != self._kind:
            raise ValueError(f"averaging: a {type(sample).__name__} among {self._kind} samples")
        if self._estimator is None:
            self._start.append(sample)
            if len(self._start) < DEFAULT_INIT_SAMPLES:
                return
            self._estimator = static_estimator(kind, self.parameters, self._start)
            held, self._start = self._start, []
        else:
            held = [sample]
        for value in held:
            self._state = self._estimator.add(
                getattr(value, "rotation", None),
                getattr(value, "translation", getattr(value, "position", None)),
                getattr(value, "covariance", None),
            )

    def compute(self, values: Inputs, timestamp_ns: int) -> dict[str, Measurement]:
        for sample in values["AB"]:
            if sample is not None:
                self._feed(sample)
                self._timestamp_ns = timestamp_ns
        state = self._state
        if state is None or state.status in (Status.INITIALISING, Status.NOT_STATIC):
            return {}
        return {"mean": state.to_measurement(timestamp_ns)}

    def progress(self) -> dict[str, Progress]:
        state = self._state
        if state is None:
            if not self._start:
                return {}
            return {
                "mean": Progress(
                    instance="",
                    status=str(Status.INITIALISING),
                    accepted=0,
                    rejected=0,
                    timestamp_ns=self._timestamp_ns,
                )
            }
        value = None
        if state.status not in (Status.INITIALISING, Status.NOT_STATIC):
            value = to_json(state.to_measurement(self._timestamp_ns))
        motion = state.motion._asdict() if state.motion is not None else None
        return {
            "mean": Progress(
                instance="",
                status=str(state.status),
                accepted=state.accepted,
                rejected=state.rejected,
                timestamp_ns=self._timestamp_ns,
                std_translation=state.std_translation,
                std_rotation=state.std_rotation,
                tolerance_translation=float(self.parameters["translation_tolerance"]),
                tolerance_rotation=math.radians(float(self.parameters["rotation_tolerance_deg"])),
                spread_translation=state.spread_translation,
                spread_rotation=state.spread_rotation,
                noise_scale=state.noise_scale,
                motion=motion,
                value=value,
            )
        }


def motion_window(samples: list[Measurement]) -> int:
    """Samples in ``MOTION_WINDOW_S`` at the rate of ``samples`` (their timestamps), between
    the estimator's default and ``MAX_MOTION_WINDOW``; the default if they span no time."""
    span_ns = samples[-1].timestamp_ns - samples[0].timestamp_ns
    if span_ns <= 0:
        return DEFAULT_MOTION_WINDOW
    rate_hz = (len(samples) - 1) * 1e9 / span_ns
    return min(max(round(MOTION_WINDOW_S * rate_hz), DEFAULT_MOTION_WINDOW), MAX_MOTION_WINDOW)
