"""Multi-tracker fusion (section 3.1.3): simultaneous estimates of one edge combined."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ubitrack_agent.core import ErrorPose, Measurement, Pose, Position3D, Rotation3D
from ubitrack_agent.services.algorithms import PoseKalmanFilter, fuse_poses
from ubitrack_agent.services.registry import (
    Inputs,
    Port,
    Pushed,
    Service,
    complete_correspondences,
    register,
)

POLICIES = ("asynchronous", "synchronised")

_REASONS = {"gated": "gated", "late": "late", "too_old": "dropped_stale"}
"""Worker counters of the filter's outcomes that publish nothing (``updated`` and
``restarted`` publish)."""


@register
class Fusion(Service):
    """Fusion of several estimates of one edge (space expansion), by one of two ``policy``:

    * ``asynchronous`` (the default, 6D only): every estimate updates an error-state Kalman
      filter with a constant-velocity model as it arrives, and the filter's pose and
      covariance at the estimate's time are published at once
      (:class:`ubitrack_agent.services.algorithms.PoseKalmanFilter`, after Ubitrack's
      ``PoseKalmanFilter`` and Welch & Bishop's SCAAT): no estimate waits for another tracker.
      Estimates arriving out of order within ``window_ms`` are re-filtered from the kept history
      (counted ``late``: their effect is in the next output), outliers are refused by the innovation
      gate ``gate`` (``gated``), the process noise is ``angular_noise`` (rad^2/s^3) and
      ``linear_noise`` (m^2/s^3), scaled on line to the innovations with ``adaptive`` (on by
      default), never below ``min_noise_scale`` times them (inputs that claim more error than
      they have would otherwise make it lag until the lag fills their claim). Each input's
      static error (an estimate's ``static_covariance``: the share of calibrations and other
      fixed static edges in its covariance) is *considered* on its own (Schmidt-Kalman), so
      fusing many samples of one input does not average a calibration's error away; at most
      ``max_sources`` inputs' at once. Its output also
      answers a query at a given time by the filter's prediction (:meth:`value_at`).
    * ``synchronised``: the worker synchronises the estimates at each trigger's time
      (``ubitrack_agent.services.triggers``) and they are fused as simultaneous: 6D on SE(3)
      (:func:`ubitrack_agent.services.algorithms.fuse_poses`), 3D positions by inverse-covariance
      weighting, 3R rotations on SO(3) by the same iteration (as poses without translation). Those
      available at the trigger's time are fused, so the output goes on while one tracker has
      lost the target. 3D and 3R estimates need this policy.

    An estimate without covariance gets ``default_sigma`` (metres and radians) on every axis,
    so plain estimates (and rotations, which carry none) get equal weights.
    """

    NAME = "fusion"
    INPUTS = {"AB": Port((Pose, ErrorPose, Position3D, Rotation3D))}
    OUTPUTS = ("fused",)
    CORRESPONDENCE = ("AB",)
    MIN_CORRESPONDENCES = 2
    PARAMETERS = {
        "default_sigma": 1e-3,
        "policy": "asynchronous",
        "angular_noise": 0.02,
        "linear_noise": 0.02,
        "gate": 27.86,
        "window_ms": 200.0,
        "adaptive": True,
        "min_noise_scale": 0.2,
        "max_sources": 8,
    }

    def __init__(self, parameters: Mapping[str, Any]) -> None:
        super().__init__(parameters)
        if self.parameters["policy"] not in POLICIES:
            raise ValueError(f"fusion: policy must be one of {POLICIES}")
        if not isinstance(self.parameters["adaptive"], bool):
            raise ValueError("fusion: adaptive must be true or false")
        self._filter = PoseKalmanFilter(
            float(self.parameters["angular_noise"]),
            float(self.parameters["linear_noise"]),
            gate=float(self.parameters["gate"]),
            window_ns=int(float(self.parameters["window_ms"]) * 1e6),
            adaptive=self.parameters["adaptive"],
            min_noise_scale=float(self.parameters["min_noise_scale"]),
            max_sources=int(self.parameters["max_sources"]),
        )
        self._published_ns: int | None = None
        """Time of the latest output: the relation's stream stays in time order."""

    def asynchronous(self) -> bool:
        return self.parameters["policy"] == "asynchronous"

    def push(self, port: str, sample: Measurement, source: str = "") -> Pushed:
        if not isinstance(sample, Pose | ErrorPose):
            raise ValueError(
                f"asynchronous fusion filters 6D poses, not {type(sample).__name__}: "
                "give 3D and 3R estimates the policy 'synchronised'"
            )
        static = sample.static_covariance if isinstance(sample, ErrorPose) else None
        outcome = self._filter.update(
            sample.timestamp_ns,
            sample.rotation,
            sample.translation,
            self._covariance(sample),
            validated=True,
            static=static,
            source=source,
        )
        if outcome in _REASONS:
            return Pushed(reason=_REASONS[outcome])
        if self._published_ns is not None and sample.timestamp_ns <= self._published_ns:
            # In time order for the filter, not for the stream: a late measurement's replay
            # gated the newest ones, so this one, older than an output already published, is
            # the newest now. It updates the filter; the next newer one is published.
            return Pushed(reason="late")
        self._published_ns = sample.timestamp_ns
        return Pushed({"fused": self.value_at("fused", sample.timestamp_ns)})

    def value_at(self, port: str, timestamp_ns: int) -> Measurement:
        return self._filter.estimate(timestamp_ns).to_measurement(timestamp_ns)

    def _covariance(self, estimate: Pose | ErrorPose) -> np.ndarray:
        if isinstance(estimate, ErrorPose):
            return estimate.covariance
        return float(self.parameters["default_sigma"]) ** 2 * np.eye(6)

    def compute(self, values: Inputs, timestamp_ns: int) -> dict[str, Measurement]:
        estimates = [row[0] for row in complete_correspondences(values, self.CORRESPONDENCE)]
        if not estimates:
            raise ValueError("no estimate available at this time")
        default = float(self.parameters["default_sigma"]) ** 2
        if all(isinstance(e, Position3D) for e in estimates):
            infos = [
                np.linalg.inv(e.covariance if e.covariance is not None else default * np.eye(3))
                for e in estimates
            ]
            covariance = np.linalg.inv(sum(infos))
            mean = covariance @ sum(i @ e.position for i, e in zip(infos, estimates, strict=True))
            return {"fused": Position3D(timestamp_ns, mean, 0.5 * (covariance + covariance.T))}
        if all(isinstance(e, Rotation3D) for e in estimates):
            fused = fuse_poses(
                np.array([e.rotation for e in estimates]),
                np.zeros((len(estimates), 3)),
                np.array([default * np.eye(6)] * len(estimates)),
            )
            return {"fused": Rotation3D(timestamp_ns, fused.rotation)}
        if not all(isinstance(e, Pose | ErrorPose) for e in estimates):
            kinds = sorted({type(e).__name__ for e in estimates})
            raise ValueError(f"cannot fuse estimates of different types: {', '.join(kinds)}")
        covariances = [self._covariance(e) for e in estimates]
        fused = fuse_poses(
            np.array([e.rotation for e in estimates]),
            np.array([e.translation for e in estimates]),
            np.array(covariances),
        )
        return {"fused": fused.to_measurement(timestamp_ns)}
