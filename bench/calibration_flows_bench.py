"""The section 4.2 calibration flows on the same recorded figure-1 data (Pustka et al., 2006).

Run: ``python -m bench.calibration_flows_bench [--seeds N] [--duration SECONDS]
[--false-alarm-seeds M]`` (defaults 20 seeds of 60 s and 40 more recordings for the live
stream's false alarms, about 18 minutes). Prints markdown tables and writes
``bench/results/calibration_flows.json``. With ``--time-gains`` it prints only the planner's
``time_gain`` of averaging and hand-eye as measured (:func:`time_gains`, from that file and a
minute of new recordings).

Each seed records the figure-1 set-up offline (:mod:`bench.figure1_recording`: the simulators'
models, camera 30 Hz, tracker 60 Hz, no ``C -> HT`` in the database) and every flow estimates
``C -> HT`` from that same recording; errors are against the simulator's truth, in the
covariance's coordinates (left perturbation in ``C``): translation in mm, rotation in degrees.

Flows (``ubitrack plan examples/paper_calibration.yaml --from C --to HT --type 6D --static
--all`` lists the first three):

* ``direct + averaging (live stream)``: per-sample ``C -> HT = (C -> WT)(WT -> ART)(ART ->
  HT)`` as the live flow computes it (90 Hz, PnP poses interpolated between camera frames:
  :func:`bench.figure1_recording.live_direct_samples`), fed one at a time to the averaging
  service's :class:`ubitrack_agent.services.algorithms.StaticEstimator` with its parameters
  (:func:`ubitrack_agent.services.components.averaging.static_estimator`: 50 samples, 0.5 mm, 0.1
  degree, a motion window of 1 s);
* ``direct + averaging (camera rate)``: the same at the camera's instants only (30 Hz);
* ``PnP through HT->Fi + averaging``: per-frame PnP of ``C -> HT`` on ``IP -> Fi`` and
  ``HT -> Fi = (HT -> ART)(ART -> WT)(WT -> Fi)``, averaged likewise;
* ``hand-eye over time``: :func:`ubitrack_agent.services.algorithms.hand_eye.hand_eye_calibration`
on every
  third frame's ``ART -> HT`` and PnP ``C -> WT`` (the closed form costs O(N^2): 0.7 s at 600
  poses, 6 s at 1,800), noise from the residuals; ``C -> HT`` is the inverse of its ``X``;
* ``hand-eye, live component``: the hand-eye service and its time expansion as the live worker
  runs them (:func:`live_hand_eye_run`: samples 5 degrees apart, at most 200, Park-Martin);
* ``time-expanded PnP``: one PnP of ``C -> HT`` over every frame's ``IP -> Fi`` and ``HT ->
  Fi`` at once (SQPNP + Levenberg-Marquardt,
  :func:`ubitrack_agent.services.algorithms.pnp.solve_pnp` on the stacked points: the paper's third
  solution expanded in space and time), with a covariance clustered by frame
  (:func:`clustered_covariance`: the tracker's error is shared by a frame's five points, so the
  pixels are not independent).

For the averaging flows also the offline optimum of the averaging step on the same samples:
the batch information-weighted mean (:func:`ubitrack_agent.services.algorithms.fuse_poses`) of the
samples the estimator accepted (the robust start's only when it rejected none of them: which ones it
rejected is not reported). Reported per flow: error against time (RMS over seeds), mean NEES
against time, time to convergence and the error then, motion-check false alarms; and the
largest move of the estimate, in its stated standard deviations, at a PnP flip (3 % of the
live stream's samples replaced by :func:`bench.static_estimate_bench.pnp_flip`).
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
from scipy import stats

from bench.figure1_recording import (
    PoseSamples,
    Recording,
    direct_samples,
    features_in_head_target,
    hand_eye_inputs,
    head_target_pnp_samples,
    live_direct_samples,
    record,
)
from bench.static_estimate_bench import pnp_flip
from bench.synthetic import left_error, rng_for
from ubitrack_agent.core import se3
from ubitrack_agent.core.uncertainty import invert_covariance
from ubitrack_agent.services.algorithms import fuse_poses
from ubitrack_agent.services.algorithms.estimate import PoseEstimate, symmetric
from ubitrack_agent.services.algorithms.hand_eye import hand_eye_calibration
from ubitrack_agent.services.algorithms.pnp import _projected, solve_pnp
from ubitrack_agent.services.algorithms.static_estimate import (
    DEFAULT_INIT_SAMPLES,
    StaticState,
    Status,
)
from ubitrack_agent.services.components.averaging import Averaging, static_estimator
from ubitrack_agent.services.expansion import TimeAccumulator
from ubitrack_agent.services.registry import lookup

RESULTS = Path(__file__).parent / "results" / "calibration_flows.json"

CHECKPOINTS_S = (2.0, 5.0, 10.0, 20.0, 30.0, 60.0)
"""Seconds of recording after which every flow's estimate is scored."""

HAND_EYE_STRIDE = 3
"""Hand-eye uses every third camera frame (10 Hz): consecutive frames add little motion."""

FLIP_RATE = 0.03
"""Share of the live stream's samples replaced by PnP flips in the flip experiment."""

AVERAGING_FLOWS: dict[str, Callable[[Recording], PoseSamples]] = {
    "direct + averaging (live stream)": live_direct_samples,
    "direct + averaging (camera rate)": direct_samples,
    "PnP through HT->Fi + averaging": head_target_pnp_samples,
}


def _score(estimate: PoseEstimate, truth: PoseEstimate) -> dict[str, float]:
    """Errors (mm, degrees), stated standard deviations (RMS over axes, mm, degrees) and NEES."""
    error = left_error(estimate, truth)
    result = {
        "error_mm": 1e3 * float(np.linalg.norm(error[3:])),
        "error_deg": float(np.degrees(np.linalg.norm(error[:3]))),
    }
    if estimate.covariance is not None:
        covariance = estimate.covariance
        result["nees"] = float(error @ np.linalg.solve(covariance, error))
        result["std_mm"] = 1e3 * float(np.sqrt(np.trace(covariance[3:, 3:])))
        result["std_deg"] = float(np.degrees(np.sqrt(np.trace(covariance[:3, :3]))))
    return result


def _state_estimate(state: StaticState) -> PoseEstimate:
    return PoseEstimate(state.rotation, state.translation, state.covariance)


def _elapsed_s(recording: Recording, time_ns: int) -> float:
    return (time_ns - int(recording.camera_ns[0])) * 1e-9


def averaging_run(
    recording: Recording, samples: PoseSamples, flips: np.ndarray | None = None
) -> dict[str, Any]:
    """Feed a flow's samples to the averaging service's estimator, one at a time."""
    truth = PoseEstimate(recording.truth_q, recording.truth_t)
    start = [samples.pose(k) for k in np.flatnonzero(samples.valid)[:DEFAULT_INIT_SAMPLES]]
    estimator = static_estimator("pose", Averaging.PARAMETERS, start)
    checkpoints = list(CHECKPOINTS_S)
    result: dict[str, Any] = {"checkpoints": {}, "converged_s": None, "not_static_s": None}
    entered: list[int] = []
    worst_flip_move = 0.0
    before = estimator.state
    for k in np.flatnonzero(samples.valid).tolist():
        elapsed = _elapsed_s(recording, int(samples.times_ns[k]))
        while checkpoints and elapsed > checkpoints[0]:
            _checkpoint(result, checkpoints.pop(0), before, samples, entered, truth)
        q, t = samples.q[k], samples.t[k]
        if flips is not None and flips[k]:
            q, t = pnp_flip(rng_for(f"flow-flip-{k}"), q, t)
        state = estimator.add(q, t, samples.cov[k])
        if before.status is Status.INITIALISING and state.status is not Status.INITIALISING:
            # The robust start's samples: which of them entered is known only by count.
            start = np.flatnonzero(samples.valid)[: DEFAULT_INIT_SAMPLES - 1].tolist()
            entered.extend(start if state.rejected == 0 else [])
        if state.last_accepted:
            entered.append(k)
        if flips is not None and flips[k] and before.covariance is not None:
            move = left_error(_state_estimate(state), _state_estimate(before))
            worst_flip_move = max(
                worst_flip_move, float(move @ np.linalg.solve(before.covariance, move)) ** 0.5
            )
        if state.converged and result["converged_s"] is None:
            result["converged_s"] = elapsed
            result["at_convergence"] = _score(_state_estimate(state), truth)
        if state.not_static and result["not_static_s"] is None:
            result["not_static_s"] = elapsed
            result["motion"] = state.motion._asdict()
        before = state
    for checkpoint in checkpoints:
        _checkpoint(result, checkpoint, before, samples, entered, truth)
    result["accepted"], result["rejected"] = before.accepted, before.rejected
    result["effective_samples"] = before.effective_samples
    if flips is not None:
        result["worst_flip_move_std"] = worst_flip_move
    return result


def _checkpoint(
    result: dict[str, Any],
    checkpoint: float,
    state: StaticState,
    samples: PoseSamples,
    entered: list[int],
    truth: PoseEstimate,
) -> None:
    if state.covariance is None:
        return
    scores = _score(_state_estimate(state), truth)
    if len(entered) > 1:
        offline = fuse_poses(samples.q[entered], samples.t[entered], samples.cov[entered])
        scores["offline_error_mm"] = _score(offline, truth)["error_mm"]
        scores["offline_error_deg"] = _score(offline, truth)["error_deg"]
    result["checkpoints"][checkpoint] = scores


def hand_eye_run(recording: Recording) -> dict[str, Any]:
    """Hand-eye calibration on the frames up to each checkpoint."""
    truth = PoseEstimate(recording.truth_q, recording.truth_t)
    head, camera = hand_eye_inputs(recording)
    frames = np.flatnonzero(head.valid & camera.valid)[::HAND_EYE_STRIDE]
    elapsed = (recording.camera_ns[frames] - recording.camera_ns[0]) * 1e-9
    result: dict[str, Any] = {"checkpoints": {}}
    for checkpoint in CHECKPOINTS_S:
        used = frames[elapsed <= checkpoint]
        try:
            x = hand_eye_calibration(
                head.q[used], head.t[used], camera.q[used], camera.t[used]
            ).eye_in_hand
        except ValueError:  # too little rotation yet
            continue
        q, t = se3.invert(x.rotation, x.translation)
        estimate = PoseEstimate(q, t, invert_covariance(x.rotation, x.translation, x.covariance))
        result["checkpoints"][checkpoint] = _score(estimate, truth)
    return result


def live_hand_eye_run(recording: Recording) -> dict[str, Any]:
    """The hand-eye component as the live worker runs it: every camera frame's ``ART -> HT``
    and ``C -> WT`` offered to its time expansion
    (:class:`ubitrack_agent.services.expansion.TimeAccumulator`: kept when 5 degrees from the last
    kept, at most 200, oldest dropped), Park-Martin on what is kept; no covariance."""
    truth = PoseEstimate(recording.truth_q, recording.truth_t)
    head, camera = hand_eye_inputs(recording)
    service = lookup("hand_eye_calibration")({})
    accumulator = TimeAccumulator(service, {})
    checkpoints = list(CHECKPOINTS_S)
    result: dict[str, Any] = {"checkpoints": {}}
    latest = None
    for k in np.flatnonzero(head.valid & camera.valid).tolist():
        elapsed = _elapsed_s(recording, int(recording.camera_ns[k]))
        while checkpoints and elapsed > checkpoints[0]:
            if latest is not None:
                result["checkpoints"][checkpoints[0]] = _score(latest, truth)
            checkpoints.pop(0)
        values = {"RH": head.pose(k), "CO": camera.pose(k)}
        if accumulator.add(values) and accumulator.ready():
            try:
                x = service.compute(accumulator.expanded(values), int(recording.camera_ns[k]))
            except ValueError:  # rotations about one axis so far
                continue
            q, t = se3.invert(x["HC"].rotation, x["HC"].translation)
            latest = PoseEstimate(q, t)
    for checkpoint in checkpoints:
        if latest is not None:
            result["checkpoints"][checkpoint] = _score(latest, truth)
    return result


def clustered_covariance(
    pose: PoseEstimate,
    points: list[np.ndarray],
    pixels: list[np.ndarray],
    camera_matrix: np.ndarray,
) -> np.ndarray:
    """Covariance of a PnP pose over several frames with errors shared within a frame: the
    cluster-robust sandwich ``H^-1 (sum_f g_f g_f^T) H^-1 F / (F - 1)``, ``H = sum J^T J``,
    ``g_f = J_f^T r_f`` the frame's gradient (Liang & Zeger, Biometrika 73(1), 1986; White,
    Econometrica 48(4), 1980)."""
    information = np.zeros((6, 6))
    gradients = []
    for frame_points, frame_pixels in zip(points, pixels, strict=True):
        projected, jacobian = _projected(frame_points, pose, camera_matrix, np.zeros(5))
        residual = (frame_pixels - projected).reshape(-1)
        information += jacobian.T @ jacobian
        gradients.append(jacobian.T @ residual)
    gradients_array = np.array(gradients)
    frames = len(gradients_array)
    inverse = np.linalg.inv(information)
    middle = gradients_array.T @ gradients_array * frames / (frames - 1)
    return symmetric(inverse @ middle @ inverse)


def time_expanded_pnp_run(recording: Recording) -> dict[str, Any]:
    """One PnP over all frames' correspondences up to each checkpoint."""
    truth = PoseEstimate(recording.truth_q, recording.truth_t)
    points = features_in_head_target(recording)
    seen = ~np.isnan(recording.pixels[..., 0])
    elapsed = (recording.camera_ns - recording.camera_ns[0]) * 1e-9
    result: dict[str, Any] = {"checkpoints": {}, "naive_nees": {}, "seconds": {}}
    for checkpoint in CHECKPOINTS_S:
        frames = np.flatnonzero((elapsed <= checkpoint) & (seen.sum(axis=1) >= 1))
        mask = np.zeros_like(seen)
        mask[frames] = seen[frames]
        started = time.perf_counter()
        pose = solve_pnp(points[mask], recording.pixels[mask], recording.camera_matrix)
        covariance = clustered_covariance(
            pose,
            [points[f][seen[f]] for f in frames],
            [recording.pixels[f][seen[f]] for f in frames],
            recording.camera_matrix,
        )
        result["seconds"][checkpoint] = time.perf_counter() - started
        result["naive_nees"][checkpoint] = _score(pose, truth)["nees"]
        result["checkpoints"][checkpoint] = _score(pose._replace(covariance=covariance), truth)
    return result


def run_seed(seed: int, duration_s: float) -> dict[str, Any]:
    """Every flow on one recording."""
    recording = record(seed, duration_s)
    flows: dict[str, Any] = {}
    for name, derive in AVERAGING_FLOWS.items():
        flows[name] = averaging_run(recording, derive(recording))
    live = live_direct_samples(recording)
    flips = rng_for(f"flow-flips-{seed}").random(len(live.q)) < FLIP_RATE
    flows["direct + averaging (live stream), 3 % flips"] = averaging_run(recording, live, flips)
    flows["hand-eye over time"] = hand_eye_run(recording)
    flows["hand-eye, live component"] = live_hand_eye_run(recording)
    flows["time-expanded PnP"] = time_expanded_pnp_run(recording)
    return flows


def _rms(values: list[float]) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if values else float("nan")


def summarise(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Per flow: RMS errors, mean NEES and mean stated standard deviations per checkpoint,
    convergence and false alarms over the seeds."""
    summary: dict[str, Any] = {}
    for name in runs[0]:
        flow = [run[name] for run in runs]
        rows = {}
        for checkpoint in CHECKPOINTS_S:
            scores = [f["checkpoints"][checkpoint] for f in flow if checkpoint in f["checkpoints"]]
            if not scores:
                continue
            row = {key: _rms([s[key] for s in scores]) for key in ("error_mm", "error_deg")}
            for key in ("nees", "std_mm", "std_deg"):
                if all(key in s for s in scores):
                    row[key] = float(np.mean([s[key] for s in scores]))
            for key in ("offline_error_mm", "offline_error_deg"):
                if all(key in s for s in scores):
                    row[key] = _rms([s[key] for s in scores])
            row["trials"] = len(scores)
            rows[checkpoint] = row
        entry: dict[str, Any] = {"checkpoints": rows}
        if "converged_s" in flow[0]:
            converged = [f for f in flow if f["converged_s"] is not None]
            entry["converged"] = len(converged)
            entry["false_alarms"] = sum(f["not_static_s"] is not None for f in flow)
            if converged:
                times = [f["converged_s"] for f in converged]
                at = [f["at_convergence"] for f in converged]
                entry["converged_s_median"] = float(np.median(times))
                entry["converged_s_max"] = float(np.max(times))
                entry["at_convergence_max_mm"] = float(max(a["error_mm"] for a in at))
                entry["at_convergence_max_deg"] = float(max(a["error_deg"] for a in at))
                entry["at_convergence_nees"] = float(np.mean([a["nees"] for a in at]))
            if "worst_flip_move_std" in flow[0]:
                entry["worst_flip_move_std"] = float(max(f["worst_flip_move_std"] for f in flow))
        if "naive_nees" in flow[0]:
            entry["naive_nees"] = {
                c: float(np.mean([f["naive_nees"][c] for f in flow])) for c in CHECKPOINTS_S
            }
            entry["solve_seconds_60"] = float(
                np.median([f["seconds"][CHECKPOINTS_S[-1]] for f in flow])
            )
        summary[name] = entry
    return summary


def print_tables(summary: dict[str, Any], seeds: int) -> None:
    low, high = (stats.chi2.ppf(p, 6 * seeds) / seeds for p in (0.025, 0.975))
    print(
        f"\nRMS error over {seeds} seeds (mm / degrees) against time; mean NEES (6 dof, 95 % "
        f"interval of the mean [{low:.2f}, {high:.2f}])\n"
    )
    header = "| flow | " + " | ".join(f"{c:g} s" for c in CHECKPOINTS_S) + " |"
    print(header)
    print("|---" * (len(CHECKPOINTS_S) + 1) + "|")
    for name, entry in summary.items():
        cells = []
        for checkpoint in CHECKPOINTS_S:
            row = entry["checkpoints"].get(checkpoint)
            if row is None:
                cells.append("-")
                continue
            cell = f"{row['error_mm']:.2f} / {row['error_deg']:.3f}"
            if "nees" in row:
                cell += f" (NEES {row['nees']:.1f})"
            cells.append(cell)
        print(f"| {name} | " + " | ".join(cells) + " |")
    print("\nAveraging flows: convergence, error then, false alarms, offline optimum at 60 s\n")
    print(
        "| flow | converged | median / max time s | max error then mm / deg | NEES then "
        "| not static | 60 s: ours / offline mm |"
    )
    print("|---|---|---|---|---|---|---|")
    for name, entry in summary.items():
        if "converged" not in entry:
            continue
        last = entry["checkpoints"][CHECKPOINTS_S[-1]]
        converged = entry["converged"]
        timing = (
            f"{entry['converged_s_median']:.1f} / {entry['converged_s_max']:.1f}"
            if converged
            else "-"
        )
        error = (
            f"{entry['at_convergence_max_mm']:.2f} / {entry['at_convergence_max_deg']:.3f}"
            if converged
            else "-"
        )
        nees = f"{entry['at_convergence_nees']:.1f}" if converged else "-"
        print(
            f"| {name} | {converged}/{seeds} | {timing} | {error} | {nees} | "
            f"{entry['false_alarms']}/{seeds} | {last['error_mm']:.3f} / "
            f"{last.get('offline_error_mm', float('nan')):.3f} |"
        )
    for name, entry in summary.items():
        if "worst_flip_move_std" in entry:
            print(f"\n{name}: largest move at a flip {entry['worst_flip_move_std']:.3g} std")
        if "naive_nees" in entry:
            naive = ", ".join(f"{c:g} s {v:.1f}" for c, v in entry["naive_nees"].items())
            print(
                f"\n{name}: NEES with the pixel-only covariance: {naive}; "
                f"solve at 60 s {1e3 * entry['solve_seconds_60']:.0f} ms"
            )


TIME_GAIN_FLOWS = {
    "averaging": "direct + averaging (live stream)",
    "hand_eye_calibration": "hand-eye over time",
}
"""Templates whose ``time_gain`` (``templates/*.yaml``) these flows measure."""
TIME_GAIN_AT_S = 10.0
"""The accumulation time the planner's ``time_gain`` refers to (``docs/planner.md``)."""


def one_sample_rms(seeds: int) -> tuple[float, float]:
    """RMS error (mm, degrees) of one live-stream sample of the direct computation over the
    first :data:`TIME_GAIN_AT_S` of ``seeds`` recordings, without PnP flips (samples whose
    rotation error exceeds ten times their recording's median): the per-sample error that an
    accumulation reduces."""
    millimetres, degrees = [], []
    for seed in range(seeds):
        recording = record(seed, TIME_GAIN_AT_S)
        samples = live_direct_samples(recording)
        truth = PoseEstimate(recording.truth_q, recording.truth_t, None)
        errors = np.array(
            [
                left_error(PoseEstimate(samples.q[k], samples.t[k], None), truth)
                for k in np.flatnonzero(samples.valid)
            ]
        )
        rotation = np.linalg.norm(errors[:, :3], axis=1)
        kept = rotation < 10 * np.median(rotation)
        millimetres += list(1e3 * np.linalg.norm(errors[kept, 3:], axis=1))
        degrees += list(np.degrees(rotation[kept]))
    return _rms(millimetres), _rms(degrees)


def time_gains(summary: dict[str, Any], seeds: int) -> dict[str, dict[str, float]]:
    """Per template of :data:`TIME_GAIN_FLOWS`: the variance of its flow's result after
    :data:`TIME_GAIN_AT_S` relative to one direct sample's (translation and rotation), from
    the summary's checkpoints (as read back from the results file) and
    :func:`one_sample_rms` on the same seeds."""
    sample_mm, sample_deg = one_sample_rms(seeds)
    gains = {}
    for template, flow in TIME_GAIN_FLOWS.items():
        row = summary[flow]["checkpoints"][str(TIME_GAIN_AT_S)]
        gains[template] = {
            "translation": (row["error_mm"] / sample_mm) ** 2,
            "rotation": (row["error_deg"] / sample_deg) ** 2,
        }
    return {"one sample": {"error_mm": sample_mm, "error_deg": sample_deg}, **gains}


FALSE_ALARM_SEED = 1000
"""First seed of the false-alarm runs (apart from the flows' seeds)."""


def false_alarm_runs(seeds: int, duration_s: float) -> list[dict[str, Any]]:
    """The live stream alone on ``seeds`` more recordings: convergence and motion check."""
    runs = []
    for seed in range(FALSE_ALARM_SEED, FALSE_ALARM_SEED + seeds):
        recording = record(seed, duration_s)
        run = averaging_run(recording, live_direct_samples(recording))
        runs.append({key: run[key] for key in ("converged_s", "not_static_s", "at_convergence")})
    return runs


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--duration", type=float, default=60.0, help="seconds per recording")
    parser.add_argument(
        "--false-alarm-seeds", type=int, default=40, help="more recordings, live stream only"
    )
    parser.add_argument(
        "--time-gains",
        action="store_true",
        help="only print the planner's time gains from the results file and --seeds recordings",
    )
    args = parser.parse_args(argv)
    if args.time_gains:
        summary = json.loads(RESULTS.read_text())["summary"]
        print(json.dumps(time_gains(summary, args.seeds), indent=1))
        return
    started = time.time()
    runs = []
    for seed in range(args.seeds):
        runs.append(run_seed(seed, args.duration))
        print(f"seed {seed} done after {time.time() - started:.0f} s", flush=True)
    summary = summarise(runs)
    print_tables(summary, args.seeds)
    alarms = false_alarm_runs(args.false_alarm_seeds, args.duration)
    fired = [run["not_static_s"] for run in alarms if run["not_static_s"] is not None]
    converged = [run["converged_s"] for run in alarms if run["converged_s"] is not None]
    worst = max(
        (run["at_convergence"]["error_mm"] for run in alarms if run["converged_s"]), default=0
    )
    print(
        f"\nlive stream on {len(alarms)} more recordings of {args.duration:g} s: not static in "
        f"{len(fired)} {fired}; converged in {len(converged)} (median {np.median(converged):.1f} "
        f"s, max {max(converged):.1f} s), largest error then {worst:.2f} mm"
    )
    summary["false alarm runs"] = alarms
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(
        json.dumps(
            {
                "command": "python -m bench.calibration_flows_bench "
                f"--seeds {args.seeds} --duration {args.duration:g}",
                "date": time.strftime("%Y-%m-%d"),
                "machine": {
                    "python": platform.python_version(),
                    "numpy": np.__version__,
                    "scipy": scipy.__version__,
                },
                "summary": summary,
                "runs": runs,
            },
            indent=1,
            default=str,
        )
    )


if __name__ == "__main__":
    main()
