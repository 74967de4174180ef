"""A minimal simulated 6D tracker: publishes noisy poses of a body on a Lissajous path.

It measures two edges, as an outside-in tracker such as an A.R.T. system does:
``<tracker>/<body>`` (dynamic, the moving body) and ``<tracker>/<reference>`` (static, a
reference target fixed in the room, re-sent once a second). Each measurement is an
:class:`~ubitrack_agent.core.ErrorPose` whose covariance is the noise actually added
(:mod:`sim_trackers.noise`).

Run ``python -m sim_trackers.pose_publisher --help``.
"""

from __future__ import annotations

import argparse
import signal
import threading
import time

import numpy as np
from scipy.spatial.transform import Rotation

from ubitrack_agent import config
from ubitrack_agent.core import encode
from ubitrack_agent.keys import KeySpace
from ubitrack_agent.session import open_session

from .noise import noise_covariance, noisy
from .trajectories import LissajousPath

REFERENCE_POSE = (Rotation.from_euler("z", 30, degrees=True).as_quat(), np.array([2.0, 1.0, 0.0]))
"""Ground truth of the static reference target in the tracker frame."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m sim_trackers.pose_publisher", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--tracker", default="ART", help="tracker frame (default: %(default)s)")
    parser.add_argument("--body", default="HT", help="moving body frame (default: %(default)s)")
    parser.add_argument("--reference", default="WT", help="static target (default: %(default)s)")
    parser.add_argument("--rate", type=float, default=60.0, help="Hz (default: %(default)s)")
    parser.add_argument("--sigma-deg", type=float, default=0.1, help="rotation noise, degrees")
    parser.add_argument("--sigma-mm", type=float, default=0.5, help="translation noise, mm")
    parser.add_argument("--seed", type=int, default=1, help="noise seed (default: %(default)s)")
    config.add_arguments(parser)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if not 0.0 < args.rate <= 10_000.0:
        raise SystemExit("--rate must be in (0, 10000] Hz")
    settings = config.from_arguments(args, role="member")
    keys = KeySpace(settings.key_prefix)
    path = LissajousPath()
    cov = noise_covariance(args.sigma_deg, args.sigma_mm)
    rng = np.random.default_rng(args.seed)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    with open_session(settings) as session:
        body = session.declare_publisher(keys.data(f"{args.tracker}/{args.body}"))
        reference = session.declare_publisher(keys.data(f"{args.tracker}/{args.reference}"))
        period_ns = int(1e9 / args.rate)
        next_tick = time.time_ns()
        last_reference = 0
        while not stop.is_set():
            now = time.time_ns()
            if now - last_reference >= 1_000_000_000:
                reference.put(encode(noisy(rng, now, *REFERENCE_POSE, cov * 0.01)))
                last_reference = now
            body.put(encode(noisy(rng, now, *path.pose(now * 1e-9), cov)))
            next_tick += period_ns
            stop.wait(max(0.0, (next_tick - time.time_ns()) * 1e-9))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
