"""Hand-eye and tip calibration: accuracy, covariance consistency (NEES) and cost.

Run: ``python -m bench.calibration_bench [--trials N]`` (default 200; N = 100 poses use a
third of them). Prints markdown tables and writes ``bench/results/calibration.json``.

* Hand-eye (:func:`bench.synthetic.noisy_hand_eye_scene`: a camera on the hand looks at a
  static target from 0.4-0.8 m within a 40 degree cone, noise levels
  ``HAND_EYE_POSE_NOISE``, drawn from the covariances handed to the estimator): errors of X
  (geodesic degrees, translation mm; median and RMS) of the closed forms (Park-Martin,
  Daniilidis, all pairs; Park-Martin on consecutive pairs, what the component did above 50
  rows) and of :func:`hand_eye_calibration` started from either, with the input covariances
  or with the noise estimated from residuals; the CRLB of X at the true poses. NEES of X and
  of the target pose RO (mean; share below the 95 % chi-square(6) bound), against the
  component's old RO covariance (the sample covariance of ``RH_i X CO_i`` over N).
* CPU time of one call against N up to 1,000 (all pairs: O(N^2)), best of 5 (2 at 1,000);
  the per-trial column of the accuracy table is the median CPU time too.
* Tip calibration (:func:`bench.synthetic.pivot_scene`: 0.15 m pointer pivoted within a 30
  degree cone and spun about its axis, isotropic tracker noise about the marker's origin):
  RMS errors of the tip in the marker and of the pivot (mm) for Ubitrack's unweighted least
  squares and for :func:`tip_calibration` (input covariances / residual noise), beside the
  CRLB; NEES against the unweighted solution with one residual variance.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import scipy
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from bench.synthetic import (
    HAND_EYE_POSE_NOISE,
    body_noise_covariances,
    hand_eye_camera_scene,
    left_error,
    noisy_hand_eye_scene,
    perturb_poses,
    perturb_with_covariances,
    pivot_scene,
    rng_for,
    rotation_error,
)
from ubitrack_agent.core import se3
from ubitrack_agent.core.uncertainty import adjoint, skew
from ubitrack_agent.services.algorithms.averaging import average_poses
from ubitrack_agent.services.algorithms.estimate import PoseEstimate, point_jacobian
from ubitrack_agent.services.algorithms.hand_eye import (
    hand_eye_calibration,
    hand_eye_daniilidis,
    hand_eye_park_martin,
)
from ubitrack_agent.services.algorithms.tip_calibration import tip_calibration

OUTPUT = Path(__file__).parent / "results" / "calibration.json"
POSE_COUNTS = (10, 30, 100)
TIMING_COUNTS = (10, 30, 100, 300, 1000)
TIP_NOISE = {
    "0.1 mm / 0.1 deg": (np.radians(0.1), 0.1e-3),
    "0.5 mm / 0.3 deg": (np.radians(0.3), 0.5e-3),
}
"""Tracker noise per marker pose: rotation about the marker's origin, displacement per axis."""
BOUND_95 = {dof: float(chi2.ppf(0.95, dof)) for dof in (3, 6)}

HandEyeMethod = Callable[[tuple, tuple], tuple[PoseEstimate, PoseEstimate | None]]


def _closed(solver: Callable, all_pairs: bool = True) -> HandEyeMethod:
    def run(poses: tuple, _covariances: tuple) -> tuple[PoseEstimate, None]:
        return solver(*poses, all_pairs=all_pairs), None

    return run


def _refined(method: str, with_covariances: bool) -> HandEyeMethod:
    def run(poses: tuple, covariances: tuple) -> tuple[PoseEstimate, PoseEstimate]:
        solution = hand_eye_calibration(
            *poses, *(covariances if with_covariances else (None, None)), method=method
        )
        return solution.eye_in_hand, solution.target_in_base

    return run


HAND_EYE_METHODS: dict[str, HandEyeMethod] = {
    "Park-Martin": _closed(hand_eye_park_martin),
    "Park-Martin consecutive pairs": _closed(hand_eye_park_martin, all_pairs=False),
    "Daniilidis": _closed(hand_eye_daniilidis),
    "Park-Martin + refinement (input cov)": _refined("park_martin", True),
    "Daniilidis + refinement (input cov)": _refined("daniilidis", True),
    "Park-Martin + refinement (residual noise)": _refined("park_martin", False),
}


def _nees(error: np.ndarray, covariance: np.ndarray) -> float:
    return float(error @ np.linalg.solve(covariance, error))


def _translation_covariance(pose: PoseEstimate, covariance: np.ndarray) -> np.ndarray:
    """3x3 covariance of the translation of ``Exp(xi) T`` (it moves by ``phi x t + rho``)."""
    jacobian = point_jacobian(pose.translation[None])[0]
    return jacobian @ covariance @ jacobian.T


def hand_eye_crlb(
    truth: PoseEstimate, hand_q: np.ndarray, hand_t: np.ndarray, covariances: tuple
) -> np.ndarray:
    """12x12 Cramér-Rao bound of (X, RO) at the true poses: residual ``Log(G_i X C_i Y^-1)``
    with Jacobian ``[Ad_{G_i}, -I]`` and covariance ``Sigma_G + Ad_{G_i X} Sigma_C Ad^T``."""
    hand_cov, eye_cov = covariances
    camera_q, camera_t = se3.compose(hand_q, hand_t, truth.rotation, truth.translation)
    transport = adjoint(camera_q, camera_t)
    residual_cov = hand_cov + transport @ eye_cov @ np.swapaxes(transport, 1, 2)
    jacobian = np.concatenate(
        (adjoint(hand_q, hand_t), np.broadcast_to(-np.eye(6), (len(hand_q), 6, 6))), axis=2
    )
    information = np.einsum("nji,njk->ik", jacobian, np.linalg.solve(residual_cov, jacobian))
    return np.linalg.inv(information)


def hand_eye_accuracy(trials: int) -> list[dict[str, Any]]:
    """Errors and NEES of every method at every noise level and pose count."""
    rows = []
    for level in HAND_EYE_POSE_NOISE:
        for n_poses in POSE_COUNTS:
            rng = rng_for(f"calibration-hand-eye-{level}-{n_poses}")
            count = trials if n_poses < 100 else max(trials // 3, 10)
            series: dict[str, dict[str, list[float]]] = {
                m: {"rot_deg": [], "trans_mm": [], "nees_x": [], "nees_ro": [], "us": []}
                for m in [*HAND_EYE_METHODS, "old RO covariance (averaged)", "CRLB"]
            }
            for _ in range(count):
                truth, target, poses, covariances = noisy_hand_eye_scene(rng, n_poses, level)
                for name, method in HAND_EYE_METHODS.items():
                    start = time.process_time()
                    x, ro = method(poses, covariances)
                    series[name]["us"].append((time.process_time() - start) * 1e6)
                    series[name]["rot_deg"].append(
                        float(np.degrees(rotation_error(x.rotation, truth.rotation)))
                    )
                    series[name]["trans_mm"].append(
                        1e3 * float(np.linalg.norm(x.translation - truth.translation))
                    )
                    if ro is not None:
                        series[name]["nees_x"].append(_nees(left_error(x, truth), x.covariance))
                        series[name]["nees_ro"].append(_nees(left_error(ro, target), ro.covariance))
                # the component before this change: Park-Martin, consecutive pairs above 50 rows
                x = hand_eye_park_martin(*poses, all_pairs=n_poses <= 50)
                qg, tg, qc, tc = poses
                averaged = average_poses(
                    *se3.compose(*se3.compose(qg, tg, x.rotation, x.translation), qc, tc)
                )
                series["old RO covariance (averaged)"]["nees_ro"].append(
                    _nees(left_error(averaged, target), averaged.covariance)
                )
                bound = hand_eye_crlb(truth, qg, tg, covariances)[:6, :6]
                series["CRLB"]["rot_deg"].append(
                    float(np.degrees(np.sqrt(np.trace(bound[:3, :3]))))
                )
                series["CRLB"]["trans_mm"].append(
                    1e3 * float(np.sqrt(np.trace(_translation_covariance(truth, bound))))
                )
            for name, values in series.items():
                rows.append(
                    {"level": level, "poses": n_poses, "trials": count, "method": name}
                    | _summary(values, dof=6, crlb=name == "CRLB")
                )
                _print_hand_eye(rows[-1])
    return rows


def _summary(values: dict[str, list[float]], dof: int, crlb: bool = False) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, series in values.items():
        if not series:
            continue
        array = np.asarray(series)
        if key.startswith("nees"):
            out[f"{key}_mean"] = float(array.mean())
            out[f"{key}_within95"] = float(np.mean(array <= BOUND_95[dof]))
        elif key == "us":
            out["median_us"] = float(np.median(array))
        elif crlb:  # per-trial bound standard deviations: RMS over trials
            out[f"{key}_rms"] = float(np.sqrt(np.mean(np.square(array))))
        else:
            out[f"{key}_median"] = float(np.median(array))
            out[f"{key}_rms"] = float(np.sqrt(np.mean(np.square(array))))
    return out


def _fmt(row: dict[str, Any], key: str, digits: int = 4) -> str:
    return f"{row[key]:.{digits}g}" if key in row else "-"


def _print_hand_eye(row: dict[str, Any]) -> None:
    print(
        f"| {row['level']} | {row['poses']} | {row['method']} | {_fmt(row, 'rot_deg_median')} "
        f"| {_fmt(row, 'rot_deg_rms')} | {_fmt(row, 'trans_mm_median')} "
        f"| {_fmt(row, 'trans_mm_rms')} | {_fmt(row, 'nees_x_mean', 3)} "
        f"| {_fmt(row, 'nees_x_within95', 3)} | {_fmt(row, 'nees_ro_mean', 3)} "
        f"| {_fmt(row, 'nees_ro_within95', 3)} | {_fmt(row, 'median_us', 3)} |"
    )


def _best_seconds(function: Callable[[], Any], repeats: int) -> float:
    """The least CPU time (all threads of the process) of ``repeats`` calls: on a shared
    machine wall time measures the other jobs as much as the call."""
    times = []
    for _ in range(repeats):
        start = time.process_time()
        function()
        times.append(time.process_time() - start)
    return min(times)


def hand_eye_timing() -> list[dict[str, Any]]:
    """CPU seconds per call against the number of poses (best of 5; of 2 at 1,000 poses)."""
    rng = rng_for("calibration-timing")
    rows = []
    for n_poses in TIMING_COUNTS:
        _, _, (qg, tg, qc, tc) = hand_eye_camera_scene(rng, n_poses)
        poses = (
            *perturb_poses(rng, qg, tg, np.radians(0.2), 1e-3),
            *perturb_poses(rng, qc, tc, np.radians(0.5), 1e-3),
        )
        repeats = 5 if n_poses < 1000 else 2
        row = {"poses": n_poses, "pairs": n_poses * (n_poses - 1) // 2}
        for name, call in {
            "park_martin_s": lambda p=poses: hand_eye_park_martin(*p),
            "daniilidis_s": lambda p=poses: hand_eye_daniilidis(*p),
            "calibration_park_martin_s": lambda p=poses: hand_eye_calibration(*p),
            "calibration_daniilidis_s": lambda p=poses: hand_eye_calibration(
                *p, method="daniilidis"
            ),
        }.items():
            row[name] = _best_seconds(call, repeats)
        rows.append(row)
        print("| " + " | ".join(f"{value:.3g}" for value in row.values()) + " |")
    return rows


def plain_least_squares(q: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ubitrack's unweighted ``[R_i, -I] (p_m, p_w) = -t_i`` and ``s^2 (A^T A)^-1`` with the
    residual variance ``s^2`` over 3N - 6 degrees of freedom."""
    rotations = Rotation.from_quat(q).as_matrix()
    design = np.concatenate((rotations, np.broadcast_to(-np.eye(3), rotations.shape)), axis=2)
    design = design.reshape(-1, 6)
    solution, residual, *_ = np.linalg.lstsq(design, -t.ravel(), rcond=None)
    variance = float(residual[0]) / (len(design) - 6)
    return solution, variance * np.linalg.inv(design.T @ design)


def tip_crlb(q: np.ndarray, pivot: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """6x6 Cramér-Rao bound of (p_m, p_w) at the true poses (see the unit tests)."""
    rotations = Rotation.from_quat(q).as_matrix()
    lever = np.concatenate((-skew(pivot), np.eye(3)), axis=1)
    design = np.concatenate((rotations, np.broadcast_to(-np.eye(3), rotations.shape)), axis=2)
    residual_cov = lever @ covariances @ lever.T
    information = np.einsum("nji,njk->ik", design, np.linalg.solve(residual_cov, design))
    return np.linalg.inv(information)


def tip_accuracy(trials: int) -> list[dict[str, Any]]:
    rows = []
    for label, (sigma_rot, sigma_t) in TIP_NOISE.items():
        for n_poses in POSE_COUNTS:
            rng = rng_for(f"calibration-tip-{label}-{n_poses}")
            keys = ("tip_mm", "pivot_mm", "nees_tip", "nees_pivot")
            series = {
                m: {k: [] for k in keys}
                for m in ("Ubitrack LS + residual variance", "ours (input cov)",
                          "ours (residual noise)", "CRLB")
            }  # fmt: skip
            for _ in range(trials):
                tip, pivot, (q_true, t_true) = pivot_scene(rng, n_poses)
                covariances = body_noise_covariances(t_true, sigma_rot, sigma_t)
                q, t = perturb_with_covariances(rng, q_true, t_true, covariances)
                plain, plain_cov = plain_least_squares(q, t)
                estimates = {
                    "Ubitrack LS + residual variance": (plain, plain_cov),
                    "ours (input cov)": _tip_estimate(tip_calibration(q, t, covariances)),
                    "ours (residual noise)": _tip_estimate(tip_calibration(q, t)),
                }
                for name, (solution, covariance) in estimates.items():
                    errors = (solution[:3] - tip, solution[3:] - pivot)
                    series[name]["tip_mm"].append(1e3 * float(np.linalg.norm(errors[0])))
                    series[name]["pivot_mm"].append(1e3 * float(np.linalg.norm(errors[1])))
                    series[name]["nees_tip"].append(_nees(errors[0], covariance[:3, :3]))
                    series[name]["nees_pivot"].append(_nees(errors[1], covariance[3:, 3:]))
                bound = tip_crlb(q_true, pivot, covariances)
                series["CRLB"]["tip_mm"].append(1e3 * float(np.sqrt(np.trace(bound[:3, :3]))))
                series["CRLB"]["pivot_mm"].append(1e3 * float(np.sqrt(np.trace(bound[3:, 3:]))))
            for name, values in series.items():
                row = {"noise": label, "poses": n_poses, "trials": trials, "method": name}
                rows.append(row | _summary(values, dof=3, crlb=name == "CRLB"))
                _print_tip(rows[-1])
    return rows


def _tip_estimate(solution: Any) -> tuple[np.ndarray, np.ndarray]:
    covariance = np.block(
        [
            [solution.tip_covariance, solution.cross_covariance],
            [solution.cross_covariance.T, solution.pivot_covariance],
        ]
    )
    return np.concatenate((solution.tip_in_marker, solution.pivot_in_tracker)), covariance


def _print_tip(row: dict[str, Any]) -> None:
    print(
        f"| {row['noise']} | {row['poses']} | {row['method']} | {_fmt(row, 'tip_mm_rms')} "
        f"| {_fmt(row, 'pivot_mm_rms')} | {_fmt(row, 'tip_mm_median')} "
        f"| {_fmt(row, 'nees_tip_mean', 3)} | {_fmt(row, 'nees_tip_within95', 3)} "
        f"| {_fmt(row, 'nees_pivot_mean', 3)} | {_fmt(row, 'nees_pivot_within95', 3)} |"
    )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=200, help="Monte Carlo trials per row")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    print(
        "| noise | N | method | X rot median deg | X rot RMS deg | X trans median mm "
        "| X trans RMS mm | NEES X mean | NEES X <= 95 % | NEES RO mean | NEES RO <= 95 % "
        "| median CPU us |\n|---|---|---|---|---|---|---|---|---|---|---|---|"
    )
    hand_eye = hand_eye_accuracy(args.trials)
    print(
        "\n| N | pairs | Park-Martin CPU s | Daniilidis CPU s | calibration (Park-Martin) CPU s "
        "| calibration (Daniilidis) CPU s |\n|---|---|---|---|---|---|"
    )
    timing = hand_eye_timing()
    print(
        "\n| tracker noise | N | method | tip RMS mm | pivot RMS mm | tip median mm "
        "| NEES tip mean | NEES tip <= 95 % | NEES pivot mean | NEES pivot <= 95 % |"
        "\n|---|---|---|---|---|---|---|---|---|---|"
    )
    tip = tip_accuracy(args.trials)
    meta = {
        "command": f"python -m bench.calibration_bench --trials {args.trials}",
        "trials": args.trials,
        "seconds": time.perf_counter() - started,
        "python": platform.python_version(),
        "scipy": scipy.__version__,
        "numpy": np.__version__,
        "hand_eye_noise": {
            level: {
                name: {"rot_deg": float(np.degrees(rot)), "t_mm": (1e3 * np.ravel(t)).tolist()}
                for name, (rot, t) in (("hand", hand), ("eye", eye))
            }
            for level, (hand, eye) in HAND_EYE_POSE_NOISE.items()
        },
        "nees_bound_95": BOUND_95,
    }
    OUTPUT.write_text(
        json.dumps({"meta": meta, "hand_eye": hand_eye, "timing": timing, "tip": tip}, indent=1)
    )
    print(f"\nwrote {OUTPUT} in {meta['seconds']:.0f} s")


if __name__ == "__main__":
    main()
