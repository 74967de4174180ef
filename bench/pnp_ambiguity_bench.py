"""PnP on the figure-1 target as the live camera sees it: how often the pose is far off, how
often it is refused as ambiguous, and whether its covariance holds (NEES), with the pixel noise
known (``pixel_sigma``, as a camera announces it) and estimated from the residuals.

Run: ``python -m bench.pnp_ambiguity_bench [--views N] [--seed S]`` (defaults 2,000 views, seed
5; about a minute). Prints a table and writes ``bench/results/pnp_ambiguity.json``.

Each view puts the camera about 2 m in front of the target of
``sim_trackers/scenarios/paper_figure1.yaml`` (its five features, nearly planar), looking at it
from random directions within about 15 degrees and offsets of 0.2 m, with 0.5 px Gaussian pixel
noise (the scenario's), once with all five features and once with one of them hidden (the
camera's occlusion). Per case: views whose rotation is more than ``--far-deg`` (10) off, views
refused (:class:`ubitrack_agent.services.algorithms.pnp.AmbiguousPose`) and how many of those the
plain solve (no ambiguity check: the residuals' noise estimate) had right, the accepted poses' mean
NEES (6 is consistent) and how many lie beyond the 3-sigma bound (NEES 20.06).
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from bench.synthetic import CAMERA_MATRIX, left_error, rotation_error
from ubitrack_agent.services.algorithms.estimate import PoseEstimate
from ubitrack_agent.services.algorithms.pnp import AmbiguousPose, project, solve_pnp
from ubitrack_agent.sim_trackers.scenario import load_scenario

RESULTS = Path(__file__).parent / "results" / "pnp_ambiguity.json"
SCENARIO = Path(__file__).parents[1] / "sim_trackers" / "scenarios" / "paper_figure1.yaml"
THREE_SIGMA_NEES = 20.06


def target() -> tuple[np.ndarray, float]:
    """The figure-1 target's features in its frame (the camera's, F1-F5 in WT) and the
    camera's pixel noise, from the scenario."""
    scenario = load_scenario(str(SCENARIO))
    world, camera = scenario.world, scenario.camera
    points = [world.pose("WT", feature, 0)[1] for feature in camera.features]
    return np.array(points), camera.noise_px


def view(rng: np.random.Generator) -> PoseEstimate:
    """The target in the camera: facing it about 2 m ahead, a little turned and shifted."""
    facing = Rotation.from_euler("y", -90, degrees=True) * Rotation.from_euler(
        "xyz", rng.normal(0.0, 0.25, 3)
    )
    ahead = np.array([rng.normal(0.0, 0.2), rng.normal(0.0, 0.2), 2.0 + rng.normal(0.0, 0.3)])
    return PoseEstimate(facing.as_quat(), ahead)


def run(views: int, seed: int, far_deg: float) -> dict[str, dict]:
    features, pixel_sigma = target()
    results = {}
    for seen in (len(features), len(features) - 1):
        rng = np.random.default_rng(seed)
        counts = {"views": 0, "far_plain": 0, "far": 0, "refused": 0, "refused_plain_right": 0}
        nees, nees_plain = [], []
        for _ in range(views):
            truth = view(rng)
            points = features[np.sort(rng.choice(len(features), seen, replace=False))]
            pixels = project(points, truth, CAMERA_MATRIX)
            pixels = pixels + rng.normal(0.0, pixel_sigma, pixels.shape)
            counts["views"] += 1
            plain = solve_pnp(points, pixels, CAMERA_MATRIX)
            plain_far = np.degrees(rotation_error(plain.rotation, truth.rotation)) > far_deg
            counts["far_plain"] += int(plain_far)
            if plain.covariance is not None:
                error = left_error(plain, truth)
                nees_plain.append(float(error @ np.linalg.solve(plain.covariance, error)))
            try:
                estimate = solve_pnp(points, pixels, CAMERA_MATRIX, pixel_sigma=pixel_sigma)
            except AmbiguousPose:
                counts["refused"] += 1
                counts["refused_plain_right"] += int(not plain_far)
                continue
            far = np.degrees(rotation_error(estimate.rotation, truth.rotation)) > far_deg
            counts["far"] += int(far)
            error = left_error(estimate, truth)
            nees.append(float(error @ np.linalg.solve(estimate.covariance, error)))
        results[f"{seen} features"] = counts | {
            "nees_mean": float(np.mean(nees)),
            "beyond_3_sigma": int(np.sum(np.array(nees) > THREE_SIGMA_NEES)),
            "plain_nees_mean": float(np.mean(nees_plain)),
            "plain_beyond_3_sigma": int(np.sum(np.array(nees_plain) > THREE_SIGMA_NEES)),
        }
    return results


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=5)
    parser.add_argument("--far-deg", type=float, default=10.0)
    args = parser.parse_args(argv)
    results = run(args.views, args.seed, args.far_deg)
    print(
        "| features seen | views | far off: plain / checked | refused (plain right) | "
        "NEES mean: plain / checked | beyond 3 sigma: plain / checked |"
    )
    print("|---|---|---|---|---|---|")
    for case, r in results.items():
        print(
            f"| {case} | {r['views']} | {r['far_plain']} / {r['far']} | {r['refused']} "
            f"({r['refused_plain_right']}) | {r['plain_nees_mean']:.2f} / {r['nees_mean']:.2f} "
            f"| {r['plain_beyond_3_sigma']} / {r['beyond_3_sigma']} |"
        )
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(
        json.dumps(
            {
                "command": f"python -m bench.pnp_ambiguity_bench --views {args.views} --seed "
                f"{args.seed} --far-deg {args.far_deg:g}",
                "date": time.strftime("%Y-%m-%d"),
                "machine": {"python": platform.python_version()},
                "results": results,
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
