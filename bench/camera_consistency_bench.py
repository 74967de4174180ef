"""Is the camera path's covariance honest, away from the live system? (issue 29)

The demo's camera-only phase (``C -> A`` from the camera alone: 2D-3D pose estimation, then the
static ``WT -> A``) reports a mean NEES of about 5.1 where an honest covariance gives 6
(``docs/performance.md``, "The demo's three phases against their steady state"). This bench
computes the same flow offline, with the live code and no network: the scenario's world
(``sim_trackers/scenarios/paper_figure1.yaml`` by default) along its trajectory, the simulated
camera's measurements (:class:`sim_trackers.sim_camera.CameraSimulator`: its pixel noise,
occlusion and announced covariance), the registered ``pose_estimation_2d3d`` and
``concatenation`` services' ``compute``, and each result's NEES against the world's truth at its
instant (the truth used for judging only). Frames the service refuses (too few features, an
ambiguous pose) are counted, as live.

Run as ``python -m bench.camera_consistency_bench [--seconds S] [--seed N] [--window S]
[--output FILE]``; prints the mean NEES with its 95 % interval, split by the number of features
seen and by ``--window`` seconds of the walk (the demo's phases last 5 s), and writes
``bench/results/camera_consistency.json``. Cost: about 2 ms per frame (the PnP and its
covariance), 30 frames a simulated second.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from ubitrack_agent.core import Pose, Position3D, Projection, quaternions
from ubitrack_agent.core.errors import MeasurementError
from ubitrack_agent.services.algorithms.estimate import PoseEstimate, nees
from ubitrack_agent.services.registry import lookup
from ubitrack_agent.sim_trackers.scenario import load_scenario
from ubitrack_agent.sim_trackers.sim_camera import CameraSimulator

RESULTS = Path(__file__).resolve().parent / "results" / "camera_consistency.json"
SECOND = 1_000_000_000


def run(seconds: float, seed: int, window_s: float = 5.0) -> dict[str, Any]:
    """The camera-only ``C -> A`` of every frame over ``seconds`` of the scenario, judged;
    the mean NEES also by ``window_s`` of the walk (the demo's phases last 5 s)."""
    scenario = load_scenario()
    world, settings = scenario.world, scenario.camera
    camera = CameraSimulator(world, settings, np.random.default_rng(seed))
    plane = world.image_planes[settings.image_plane]
    projection = Projection(0, plane.projection_matrix())
    pnp, chain = lookup("pose_estimation_2d3d")({}), lookup("concatenation")({})
    target = next(e for e in scenario.database_edges if e.type == "3D").source  # WT
    features = {
        f: Position3D(0, world.pose(target, f, 0)[1]) for f in settings.features
    }  # static, as the database serves them
    augmentation = Pose(0, *world.pose(target, "A", 0))
    by_count: dict[int, list[float]] = {}
    by_window: dict[int, list[float]] = {}
    errors_mm: list[float] = []
    errors_deg: list[float] = []
    refused: dict[str, int] = {}
    for k in range(int(seconds * settings.rate)):
        t_ns = SECOND + k * SECOND // int(settings.rate)
        seen = camera.measure(t_ns)
        names = [f for f in settings.features if f"{settings.image_plane}_{f}" in seen]
        values = {
            "CI": projection,
            "IF": [seen[f"{settings.image_plane}_{f}"] for f in names],
            "OF": [features[f] for f in names],
        }
        try:
            c_wt = pnp.compute(values, t_ns)["CO"]
        except (ValueError, MeasurementError, ArithmeticError) as exc:  # as the worker counts
            reason = type(exc).__name__
            refused[reason] = refused.get(reason, 0) + 1
            continue
        c_a = chain.compute({"AB": c_wt, "BC": augmentation}, t_ns)["AC"]
        truth = PoseEstimate(*world.pose(plane.camera, "A", t_ns))
        value = nees(PoseEstimate(c_a.rotation, c_a.translation, c_a.covariance), truth)
        if value is not None:
            by_count.setdefault(len(names), []).append(value)
            by_window.setdefault(int((t_ns - SECOND) / SECOND // window_s), []).append(value)
        errors_mm.append(1e3 * float(np.linalg.norm(c_a.translation - truth.translation)))
        relative = quaternions.multiply(quaternions.conjugate(truth.rotation), c_a.rotation)
        errors_deg.append(float(np.degrees(quaternions.angle(relative))))
    every = [v for values in by_count.values() for v in values]
    return {
        "frames": int(seconds * settings.rate),
        "refused": refused,
        "rms_mm": float(np.sqrt(np.mean(np.square(errors_mm)))),
        "rms_deg": float(np.sqrt(np.mean(np.square(errors_deg)))),
        "mean_nees": _summary(every),
        "by_features_seen": {str(n): _summary(v) for n, v in sorted(by_count.items())},
        "window_s": window_s,
        "mean_nees_by_window": [float(np.mean(by_window[k])) for k in sorted(by_window)],
    }


def _summary(values: list[float]) -> dict[str, float]:
    """Mean NEES, its 95 % interval for an honest 6-DoF covariance over as many independent
    samples (chi-square), the median and the share beyond 20.06 (3 sigma)."""
    n = len(values)
    low, high = stats.chi2.ppf([0.025, 0.975], 6 * n) / n if n else (float("nan"),) * 2
    return {
        "samples": n,
        "mean": float(np.mean(values)) if n else float("nan"),
        "honest_interval": [float(low), float(high)],
        "median": float(np.median(values)) if n else float("nan"),
        "beyond_3_sigma": float(np.mean(np.array(values) > 20.06)) if n else float("nan"),
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=120.0, help="(default: 120)")
    parser.add_argument("--seed", type=int, default=1, help="the camera's noise (default: 1)")
    parser.add_argument(
        "--window", type=float, default=5.0, help="seconds of each window's mean (default: 5)"
    )
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    started = time.perf_counter()
    result = run(args.seconds, args.seed, args.window)
    result.update(seconds=args.seconds, seed=args.seed, took_s=time.perf_counter() - started)
    mean = result["mean_nees"]
    print(
        f"{mean['samples']} of {result['frames']} frames judged, refused {result['refused']}: "
        f"RMS {result['rms_mm']:.3f} mm / {result['rms_deg']:.4f} deg, "
        f"mean NEES {mean['mean']:.2f} (honest: {mean['honest_interval'][0]:.2f}-"
        f"{mean['honest_interval'][1]:.2f}), median {mean['median']:.2f}, "
        f"beyond 3 sigma {100 * mean['beyond_3_sigma']:.2f} %"
    )
    windows = result["mean_nees_by_window"]
    print(
        f"  mean NEES by {args.window:g} s of the walk: from {min(windows):.2f} to "
        f"{max(windows):.2f} (median {float(np.median(windows)):.2f}; honest, one window of "
        f"{args.window * 30:.0f} frames: about 6 +- {2 * np.sqrt(12 / (args.window * 30)):.2f})"
    )
    for count, summary in result["by_features_seen"].items():
        print(
            f"  {count} features seen: {summary['samples']} frames, mean NEES {summary['mean']:.2f}"
        )
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=2) + "\n")
    print(f"written to {args.output}")


if __name__ == "__main__":
    main()
