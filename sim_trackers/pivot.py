"""A pointer turned about its tip on a fixed pivot, as in a tip (pivot) calibration.

The user holds the pointer's tip in a divot fixed in the tracker's frame and turns the pointer
about it (Tuceryan et al., "Calibration requirements and procedures for a monitor-based
augmented reality system", IEEE TVCG 1(3), 1995; Ubitrack's ``TipCalibration``).
:class:`PivotMotion` is the ground truth, a pure function of time: the pose of the pointer's
marker M in the tracker T while the tip, at a known offset in M, stays on the pivot. Run as a
process it is a tracker that announces ``T -> M`` (6D, dynamic) and publishes ``ErrorPose``
samples with noise about the marker's origin (:mod:`ubitrack_agent.sim_trackers.noise`) and the
covariance of that noise; the tip and the pivot are never published, so a test can check a
calibration against them.

Run: ``python -m ubitrack_agent.sim_trackers.pivot --provider pointer --tracker T --marker M
[--sigma-mm 0.2] [--sigma-deg 0.1] [--rate 60]`` plus the zenoh flags of ``ubitrack config``.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ubitrack_agent.core import ErrorPose
from ubitrack_agent.core.uncertainty import in_place_covariance, isotropic_pose_covariance
from ubitrack_agent.io.provider import EdgeAnnouncement
from ubitrack_agent.net import config
from ubitrack_agent.net.clock import Clock
from ubitrack_agent.net.lifecycle import stop_on_signals
from ubitrack_agent.sim_trackers.noise import perturb_in_place
from ubitrack_agent.sim_trackers.runtime import provider_session, run_periodic

_GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0
"""Ratio of the tilt plane's turn to the tilt's period: irrational, so the motion never
repeats and covers every tilt direction."""


@dataclass(frozen=True)
class PivotMotion:
    """The marker of a pointer pivoting on a fixed point (metres, degrees, seconds).

    The pointer's axis (from the tip to the marker's origin) points at the tracker (along its
    -z) at rest and tilts by up to ``cone_deg`` about the pivot, sinusoidally with period
    ``period_s``, in a vertical plane that turns slowly about the tracker's z axis; meanwhile
    the pointer rolls about its own axis by up to ``roll_deg``. The rotations span all three
    axes, as a tip calibration needs.
    """

    tip: tuple[float, float, float] = (0.012, -0.008, -0.15)
    """The tip in the marker's frame."""
    pivot: tuple[float, float, float] = (0.1, -0.05, 1.2)
    """The pivot (where the tip rests) in the tracker's frame."""
    cone_deg: float = 25.0
    period_s: float = 4.0
    roll_deg: float = 30.0

    def pose(self, time_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Rotation quaternion (x, y, z, w) and translation of the marker in the tracker."""
        phase = 2.0 * np.pi * time_s / self.period_s
        tip = np.asarray(self.tip, dtype=float)
        upright, _ = Rotation.align_vectors([[0.0, 0.0, -1.0]], [-tip / np.linalg.norm(tip)])
        rotation = (
            Rotation.from_euler("z", _GOLDEN * phase)
            * Rotation.from_euler("x", np.radians(self.cone_deg) * np.sin(phase))
            * Rotation.from_euler("z", np.radians(self.roll_deg) * np.sin(1.37 * phase))
            * upright
        )
        return rotation.as_quat(), np.asarray(self.pivot, dtype=float) - rotation.apply(tip)


def main() -> int:
    parser = argparse.ArgumentParser(prog="python -m ubitrack_agent.sim_trackers.pivot")
    parser.add_argument("--provider", required=True, help="provider id")
    parser.add_argument("--tracker", default="T", help="tracker frame name")
    parser.add_argument("--marker", default="M", help="the pointer's marker frame name")
    parser.add_argument("--rate", type=float, default=60.0, help="samples per second")
    parser.add_argument("--sigma-mm", type=float, default=0.2, help="position noise per axis")
    parser.add_argument("--sigma-deg", type=float, default=0.1, help="rotation noise per axis")
    parser.add_argument("--seed", type=int, default=0, help="noise seed")
    config.add_arguments(parser)
    args = parser.parse_args()
    settings = config.from_arguments(args, role="member")
    stop = stop_on_signals()
    motion = PivotMotion()
    rng = np.random.default_rng(args.seed)
    sigma_m = args.sigma_mm / 1000.0
    noise = isotropic_pose_covariance(np.radians(args.sigma_deg), sigma_m)
    edge = EdgeAnnouncement(args.tracker, args.marker, "6D", rate=args.rate, sigma=sigma_m)
    clock = Clock.of(settings)
    with provider_session(settings, args.provider, [edge]) as provider:

        def step(now_ns: int) -> None:
            q, t = perturb_in_place(rng, *motion.pose(now_ns * 1e-9), noise)
            stamp = clock.reading(now_ns)
            provider.publish(edge.name, ErrorPose(stamp, q, t, in_place_covariance(t, noise)))

        run_periodic(args.rate, step, stop)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
