"""Is the fusion filter's covariance honest? NEES over independent runs (issue 29).

Run: ``python -m bench.fusion_consistency_bench [--runs N] [--seconds S] [--floors F,F]
[--noise-factor X] [--output FILE]`` (defaults: 12 runs of 20 s, about 2 minutes; writes
``bench/results/fusion_consistency.json``). ``--floors``: the adaptive filter also with each
least factor of its noise (``min_noise_scale``); ``--noise-factor``: the sensors' true noise
that many times what they announce (below 1: inputs that over-claim, as exact simulated
trackers do, where the adaptive noise without a floor falls until the filter lags).

The figure-1 world offline (``sim_trackers/scenarios/paper_figure1.yaml``, its rates, noise,
dropout and occlusion): the two estimates of ``C -> A`` the figure-6 flow fuses, made as the
live flow makes them, fed to :class:`~ubitrack_agent.services.algorithms.PoseKalmanFilter` in
time order, and every posterior it publishes judged against the truth at its stamp:

* the **A.R.T. path** at the tracker's rate: a noisy ``ART -> HT`` (the simulator's in-place
  noise, announced with its covariance) inverted and concatenated with ``C -> HT``, the static
  ``ART -> WT`` and ``WT -> A`` (``core.poses``: covariances propagated to first order);
* the **camera path** at the camera's rate: the features' pixels with their noise, a 2D-3D pose
  (:func:`~ubitrack_agent.services.algorithms.solve_pnp`, covariance from the pixel noise)
  concatenated with ``WT -> A``.

Each run draws the static edges' errors once from their announced covariances, as a real room
holds one calibration for a whole session: ``ART -> WT`` (``--static-mm``, ``--static-deg``)
and, in the world *calibrated*, ``C -> HT`` as a live calibration leaves it (``--calibration-mm``,
``--calibration-deg``, the demo's 0.1-0.4 mm); in the world *exact* ``C -> HT`` is the truth
without a covariance, as ``bench.switch_bench``'s database serves it.

Filters (:class:`~ubitrack_agent.services.algorithms.PoseKalmanFilter`), on the same
measurements of each run: the template's process noise (``templates/fusion.yaml``) and that
noise times ``--scales``; ``adaptive``, the noise scaled on line until the innovations' NIS has
its expectation (Bar-Shalom, Li, Kirubarajan, *Estimation with Applications to Tracking and
Navigation*, 2001, section 11.2, adjustable level process noise), alone tried and not adopted
(below); and each path's static error *considered* (the filter told which part of each
estimate's covariance is its static edges' share, propagated as the rest; the camera path has
none here), with the template's noise and adaptive (``docs/performance.md``, "Is the fused
covariance honest?").

Why runs: the samples of one run are not independent (a filtered output's errors are
correlated over its time constant, and every sample of a run shares its static errors), so the
mean NEES of ``n`` samples of one run is not chi-square(6 n) / n. The test of consistency is
over independent runs (Bar-Shalom et al., section 5.4.2, "Monte Carlo runs"): each run's mean
NEES has expectation 6 when the covariance is honest; their mean is judged by the t interval of
the runs' spread (95 %); the chi-square interval a single run's ``n`` samples would have if
independent is printed beside it, to show how much narrower it is. The simulator's truth is
used only for judging.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from scipy.stats import chi2

from bench.synthetic import THREE_SIGMA_NEES, nees, nees_over_batches, rotation_error
from ubitrack_agent.core import ErrorPose, Pose
from ubitrack_agent.core.poses import compose_poses, invert_pose
from ubitrack_agent.core.uncertainty import in_place_covariance, isotropic_pose_covariance
from ubitrack_agent.services.algorithms import PoseKalmanFilter, solve_pnp
from ubitrack_agent.services.algorithms.estimate import PoseEstimate
from ubitrack_agent.sim_trackers.noise import perturb_in_place
from ubitrack_agent.sim_trackers.scenario import DEFAULT_SCENARIO, Scenario, load_scenario

PATHS = ("A.R.T.", "camera")
"""The fusion's two inputs, each with its own static error."""
OUTPUT = Path(__file__).parent / "results" / "fusion_consistency.json"
WARM_UP_S = 3.0
"""Posteriors of a run's first seconds are not judged: the filter's start is the switch
bench's subject, this bench's the steady state."""


@dataclass(frozen=True)
class Measurement:
    """One estimate of ``C -> A`` as the fusion receives it, and the truth at its stamp."""

    path: str
    estimate: ErrorPose
    truth: PoseEstimate
    static: np.ndarray
    """The part of the estimate's covariance from its static edges (the rest is white)."""

    @property
    def white(self) -> np.ndarray:
        """The part of the estimate's covariance from its dynamic edges."""
        return self.estimate.covariance - self.static


def static_edge(
    scenario: Scenario, rng: np.random.Generator, source: str, target: str, sigma: np.ndarray
) -> ErrorPose:
    """``source -> target`` with an error drawn once from ``sigma`` (in place) and announced
    with it."""
    rotation, translation = scenario.world.pose(source, target, 0)
    rotation, translation = perturb_in_place(rng, rotation, translation, sigma)
    return ErrorPose(0, rotation, translation, in_place_covariance(translation, sigma))


def exact(pose: ErrorPose) -> Pose:
    """``pose`` without its covariance: what the concatenation carries of the other edges'."""
    return Pose(pose.timestamp_ns, pose.rotation, pose.translation)


def measurements(
    scenario: Scenario, seed: int, seconds: float, calibrated: bool, args: argparse.Namespace
) -> list[Measurement]:
    """One run's estimates of ``C -> A`` from both paths, in time order."""
    rng = np.random.default_rng(seed)
    world, art, camera = scenario.world, scenario.art, scenario.camera
    art_sigma = isotropic_pose_covariance(
        math.radians(art.noise.rotation_deg), art.noise.position_mm / 1e3
    )
    static_sigma = isotropic_pose_covariance(math.radians(args.static_deg), args.static_mm / 1e3)
    art_wt = static_edge(scenario, rng, art.frame, "WT", static_sigma)
    if calibrated:
        calibration_sigma = isotropic_pose_covariance(
            math.radians(args.calibration_deg), args.calibration_mm / 1e3
        )
        c_ht: Pose | ErrorPose = static_edge(scenario, rng, "C", "HT", calibration_sigma)
    else:
        c_ht = Pose(0, *world.pose("C", "HT", 0))
    wt_a = Pose(0, *world.pose("WT", "A", 0))
    plane = world.image_planes[camera.image_plane]
    features = np.array([world.pose("WT", name, 0)[1] for name in camera.features])
    start_ns = 1_000_000_000
    stamps = [
        (start_ns + round(k / art.rate * 1e9), "A.R.T.") for k in range(int(seconds * art.rate))
    ]
    offset = rng.uniform(0.0, 1.0 / camera.rate)
    stamps += [
        (start_ns + round((k / camera.rate + offset) * 1e9), "camera")
        for k in range(int(seconds * camera.rate))
    ]
    made = []
    for stamp, path in sorted(stamps):
        if path == "A.R.T.":
            if rng.random() < art.dropout:
                continue
            rotation, translation = world.pose(art.frame, "HT", stamp)
            rotation, translation = perturb_in_place(
                rng, rotation, translation, art_sigma * args.noise_factor**2
            )
            art_ht = ErrorPose(
                stamp, rotation, translation, in_place_covariance(translation, art_sigma)
            )
            estimate = compose_poses(
                compose_poses(compose_poses(c_ht, invert_pose(art_ht)), art_wt), wt_a
            )
            static = compose_poses(
                compose_poses(compose_poses(c_ht, invert_pose(exact(art_ht))), art_wt), wt_a
            ).covariance
        else:
            rotation, translation = world.pose("C", "WT", stamp)
            seen = world.project(camera.image_plane, camera.features, stamp)
            kept = [
                i
                for i, name in enumerate(camera.features)
                if name in seen and rng.random() >= camera.occlusion
            ]
            pixels = np.array([seen[camera.features[i]] for i in kept])
            pixels = pixels + rng.normal(0.0, camera.noise_px * args.noise_factor, pixels.shape)
            try:
                pose = solve_pnp(
                    features[kept],
                    pixels,
                    plane.matrix,
                    plane.distortion,
                    pixel_sigma=camera.noise_px,
                )
            except ValueError:  # too few points, or an ambiguous pose the live flow also drops
                continue
            c_wt = ErrorPose(stamp, pose.rotation, pose.translation, pose.covariance)
            estimate = compose_poses(c_wt, wt_a)
            static = np.zeros((6, 6))
        truth = PoseEstimate(*world.pose("C", "A", stamp))
        made.append(Measurement(path, estimate, truth, static))
    return made


def fed(filter_: PoseKalmanFilter, m: Measurement, considering: bool) -> bool:
    """Whether ``filter_`` took ``m``: its whole covariance, or, ``considering``, told which
    part is its path's static error."""
    e = m.estimate
    static = {"static": m.static, "source": m.path} if considering else {}
    outcome = filter_.update(e.timestamp_ns, e.rotation, e.translation, e.covariance, **static)
    return outcome in ("updated", "restarted")


def judge(filter_: PoseKalmanFilter, considering: bool, run: list[Measurement]) -> dict[str, Any]:
    """Feed one run to ``filter_`` (``considering``: :func:`fed`); the NEES, 3-sigma count and
    error of what it publishes, and the CPU time of an update (the mean over the run, process
    time: what a fusion worker pays per sample for the filter)."""
    values, errors_mm, errors_deg = [], [], []
    first_ns = run[0].estimate.timestamp_ns
    updating_s = 0.0
    for m in run:
        e = m.estimate
        began = time.process_time()
        taken = fed(filter_, m, considering)
        updating_s += time.process_time() - began
        if not taken:
            continue
        if e.timestamp_ns - first_ns < WARM_UP_S * 1e9:
            continue
        published = filter_.estimate(e.timestamp_ns)
        values.append(nees(published, m.truth))
        errors_mm.append(1e3 * float(np.linalg.norm(published.translation - m.truth.translation)))
        errors_deg.append(math.degrees(rotation_error(published.rotation, m.truth.rotation)))
    array = np.array(values)
    return {
        "samples": len(array),
        "nees_mean": float(array.mean()),
        "beyond_3_sigma": int((array > THREE_SIGMA_NEES).sum()),
        "error_mm_rms": float(np.sqrt(np.mean(np.square(errors_mm)))),
        "error_deg_rms": float(np.sqrt(np.mean(np.square(errors_deg)))),
        "update_us": 1e6 * updating_s / len(run),
    }


def inputs_nees(run: list[Measurement], path: str) -> float:
    """The mean NEES of one path's estimates themselves (no filter)."""
    return float(np.mean([nees(m.estimate, m.truth) for m in run if m.path == path]))


def filters(scales: list[float], floors: list[float] = ()) -> dict[str, tuple[Any, bool]]:
    """Name -> (factory of the filter, whether it is told the static parts) of each filter
    compared, on the template's process noise."""
    template = yaml.safe_load(
        (Path(__file__).parents[1] / "templates" / "fusion.yaml").read_text()
    )["parameters"]
    angular, linear = template["angular_noise"], template["linear_noise"]
    made: dict[str, tuple[Any, bool]] = {
        f"template x {s:g}": ((lambda s=s: PoseKalmanFilter(s * angular, s * linear)), False)
        for s in scales
    }
    adaptive = lambda: PoseKalmanFilter(angular, linear, adaptive=True)  # noqa: E731
    made["innovation-matched (tried)"] = (adaptive, False)
    made["consider"] = (lambda: PoseKalmanFilter(angular, linear), True)
    made["consider, innovation-matched"] = (adaptive, True)
    for floor in floors:
        made[f"consider, innovation-matched, at least x {floor:g}"] = (
            lambda floor=floor: PoseKalmanFilter(
                angular, linear, adaptive=True, min_noise_scale=floor
            ),
            True,
        )
    return made


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=12, help="independent runs per world")
    parser.add_argument("--seconds", type=float, default=20.0, help="length of a run")
    parser.add_argument("--scales", default="1,0.1,0.01", help="process noise factors to try")
    parser.add_argument(
        "--floors", default="", help="least factors of the adaptive noise to try (comma-separated)"
    )
    parser.add_argument(
        "--noise-factor",
        type=float,
        default=1.0,
        help="the sensors' true noise over what they announce (below 1: inputs that over-claim)",
    )
    parser.add_argument("--static-mm", type=float, default=0.05, help="ART -> WT's error (sigma)")
    parser.add_argument("--static-deg", type=float, default=0.01)
    parser.add_argument("--calibration-mm", type=float, default=0.2, help="C -> HT's (sigma)")
    parser.add_argument("--calibration-deg", type=float, default=0.02)
    parser.add_argument("--output", type=Path, default=OUTPUT)
    args = parser.parse_args(argv)
    if args.runs < 2:
        parser.error("--runs: at least 2 (the interval is over runs)")
    scenario = load_scenario(DEFAULT_SCENARIO)
    floors = [float(f) for f in args.floors.split(",") if f]
    makers = filters([float(s) for s in args.scales.split(",")], floors)
    began = time.time()
    worlds: dict[str, Any] = {}
    for world, calibrated in (("calibrated", True), ("exact", False)):
        per_filter: dict[str, list[dict[str, Any]]] = {name: [] for name in makers}
        inputs: dict[str, list[float]] = {path: [] for path in PATHS}
        for run_index in range(args.runs):
            run = measurements(scenario, 1000 + run_index, args.seconds, calibrated, args)
            for path in inputs:
                inputs[path].append(inputs_nees(run, path))
            for name, (make, considering) in makers.items():
                per_filter[name].append(judge(make(), considering, run))
        worlds[world] = {
            "inputs": {path: nees_over_batches(values) for path, values in inputs.items()},
            "filters": {
                name: {
                    "nees": nees_over_batches([r["nees_mean"] for r in runs]),
                    "samples": sum(r["samples"] for r in runs),
                    "beyond_3_sigma": sum(r["beyond_3_sigma"] for r in runs),
                    "error_mm_rms": float(np.median([r["error_mm_rms"] for r in runs])),
                    "error_deg_rms": float(np.median([r["error_deg_rms"] for r in runs])),
                    "update_us_median": float(np.median([r["update_us"] for r in runs])),
                    "one_run_chi2_interval_95": [
                        chi2.ppf(q, 6 * runs[0]["samples"]) / runs[0]["samples"]
                        for q in (0.025, 0.975)
                    ],
                }
                for name, runs in per_filter.items()
            },
        }
    result = {
        "command": "python -m bench.fusion_consistency_bench "
        f"--runs {args.runs} --seconds {args.seconds:g} --scales {args.scales}"
        + (f" --floors {args.floors}" if args.floors else "")
        + (f" --noise-factor {args.noise_factor:g}" if args.noise_factor != 1.0 else ""),
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "seconds": round(time.time() - began, 1),
        "settings": {k: v for k, v in vars(args).items() if k != "output"},
        "worlds": worlds,
    }
    print_tables(result)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=1, default=str))
    print(f"\nwritten to {args.output}")


def print_tables(result: dict[str, Any]) -> None:
    for world, w in result["worlds"].items():
        print(f"\nC -> HT {world}")
        print("| estimates | mean NEES over runs (95 % interval) | consistent |")
        print("|---|---|---|")
        for path, s in w["inputs"].items():
            low, high = s["interval_95"]
            interval = f"{s['mean']:.2f} ({low:.2f}-{high:.2f})"
            print(f"| {path} path, unfiltered | {interval} | {s['consistent']} |")
        print(
            "| filter | mean NEES over runs (95 % interval) | consistent | one run's chi-square "
            "interval | beyond 3 sigma | RMS error mm / deg (median run) | update us (median run) |"
        )
        print("|---|---|---|---|---|---|---|")
        for name, f in w["filters"].items():
            low, high = f["nees"]["interval_95"]
            one_low, one_high = f["one_run_chi2_interval_95"]
            print(
                f"| {name} | {f['nees']['mean']:.2f} ({low:.2f}-{high:.2f}) | "
                f"{f['nees']['consistent']} | {one_low:.2f}-{one_high:.2f} | "
                f"{f['beyond_3_sigma']} of {f['samples']} | {f['error_mm_rms']:.2f} / "
                f"{f['error_deg_rms']:.3f} | "
                f"{f['update_us_median']:.0f} |"
            )


if __name__ == "__main__":
    main()
