"""A noise-free 6D tracker for tests and benchmarks: announces ``T->WT`` (static, unless
``--hide-world``) and ``T->HT`` (dynamic) through the sensor API and publishes them from
ground truth, so a test knows the true ``WT->HT`` at any time (:func:`true_wt_ht`). The
published covariance is the announced accuracy ``sigma`` on every axis, so two trackers are
told apart by it. The truth is a function of real time; samples are stamped on the process's
clock (``--clock-offset-ms``: a tracker whose host's clock is off), so ``true_wt_ht`` of a
sample's timestamp is the truth only once the timestamp is corrected to real time.

Run: ``python -m ubitrack_agent.sim_trackers.exact_tracker --provider art --tracker ART --yaw 30
...``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.spatial.transform import Rotation

from ubitrack_agent.core import ErrorPose, se3
from ubitrack_agent.io.provider import EdgeAnnouncement, Provider
from ubitrack_agent.net import config
from ubitrack_agent.net.clock import Clock
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.lifecycle import stop_on_signals
from ubitrack_agent.net.session import open_session
from ubitrack_agent.sim_trackers.trajectories import LissajousPath

PATH = LissajousPath(centre=(0.0, 0.0, 1.6), amplitude=(1.0, 0.5), frequency=(0.05, 0.1))
"""At most 0.45 m/s: a sample held for the 5 ms synchronisation tolerance is off by 2.2 mm."""


def tracker_pose(yaw_deg: float, x: float) -> tuple[np.ndarray, np.ndarray]:
    """Pose of WT in the tracker frame."""
    return Rotation.from_euler("z", yaw_deg, degrees=True).as_quat(), np.array([x, 1.0, 0.5])


def true_wt_ht(timestamp_ns: int) -> tuple[np.ndarray, np.ndarray]:
    return PATH.pose(timestamp_ns * 1e-9)


def main() -> int:
    parser = argparse.ArgumentParser(prog="python -m ubitrack_agent.sim_trackers.exact_tracker")
    parser.add_argument("--provider", required=True, help="provider id")
    parser.add_argument("--tracker", required=True, help="tracker frame name")
    parser.add_argument("--yaw", type=float, default=0.0, help="tracker yaw about z, degrees")
    parser.add_argument("--x", type=float, default=2.0, help="tracker x offset, metres")
    parser.add_argument("--rate", type=float, default=100.0)
    parser.add_argument("--sigma", type=float, default=1e-3, help="announced accuracy (m)")
    parser.add_argument(
        "--hide-world",
        action="store_true",
        help="announce only T->HT: where the tracker stands must then be calibrated",
    )
    config.add_arguments(parser)
    args = parser.parse_args()
    settings = config.from_arguments(args, role="member")
    clock = Clock.of(settings)
    stop = stop_on_signals()
    cov = np.diag([args.sigma**2] * 6)
    q_wt, t_wt = tracker_pose(args.yaw, args.x)
    edges = [
        EdgeAnnouncement(args.tracker, "HT", "6D", name="HT", rate=args.rate, sigma=args.sigma),
    ]
    if not args.hide_world:
        edges.append(
            EdgeAnnouncement(args.tracker, "WT", "6D", static=True, name="WT", sigma=args.sigma)
        )
    with (
        open_session(settings) as session,
        Provider(
            session, KeySpace(settings.key_prefix), args.provider, edges, settings.host_name
        ) as provider,
    ):
        if not args.hide_world:
            provider.publish("WT", ErrorPose(clock.now_ns(), q_wt, t_wt, cov))
        while not stop.wait(1.0 / args.rate):
            now = time.time_ns()
            q, t = se3.compose(q_wt, t_wt, *true_wt_ht(now))
            provider.publish("HT", ErrorPose(clock.reading(now), q, t, cov))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
