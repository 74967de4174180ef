"""Monte Carlo of the static estimator (:mod:`ubitrack_agent.services.algorithms.static_estimate`).

Run: ``python -m bench.static_estimate_bench [--trials N] [--long N]`` (defaults 500 trials,
100 long runs). Prints one table and writes ``bench/results/static_estimate.json``:

* NEES of the final estimate (6 dof) over seeded trials with honest sample covariances,
  3x optimistic ones (true noise 3x the stated standard deviations), both with 3 % PnP-flip
  outliers, an error shared by all samples, samples without covariance, and noise correlated
  in time (AR(1), 0.6 and 0.9 per sample); with the two-sided 95 % chi-square interval of the
  mean NEES (for a covariance estimated on as many degrees of freedom as the estimator's
  batches give);
* outlier immunity: the largest move of the estimate caused by a flip, in the estimate's
  standard deviations (always 0 if every flip is rejected), and the fraction of flips
  rejected;
* the motion check: false alarms over long static runs (10,000 samples each, 1 % flips;
  independent noise and AR(1) noise of 0.6 and 0.9), detection delay of a 5 mm/s drift, of a
  2 degree/s rotation, and of a 2 cm and a 5 mm jump.

The stream generators are shared with ``tests/unit/test_alg_static_estimate.py``.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
from scipy import stats
from scipy.spatial.transform import Rotation

from bench.synthetic import left_error, random_quaternion, rng_for
from ubitrack_agent.services.algorithms.estimate import PoseEstimate, perturb_left, rigid
from ubitrack_agent.services.algorithms.static_estimate import BATCHES, StaticEstimator, StaticState

RESULTS = Path(__file__).parent / "results" / "static_estimate.json"

PNP_COVARIANCE = np.diag([1e-4, 1e-4, 4e-4, 1e-6, 4e-6, 1e-6])
"""Per-frame covariance of a camera-to-target pose from PnP: 0.6-1.1 degrees, 1-2 mm."""

RATE_HZ = 30.0
"""Sample rate of the streams (a camera)."""


def random_truth(rng: np.random.Generator) -> PoseEstimate:
    """A pose about 1.5 m away in a random orientation."""
    return PoseEstimate(random_quaternion(rng), np.array([0.3, -0.2, 1.5]) + rng.normal(0, 0.1, 3))


def pnp_flip(rng: np.random.Generator, truth_q: np.ndarray, truth_t: np.ndarray):
    """A PnP-flip-like gross error: 30-50 degrees about a random axis, 0.5-1.5 m away."""
    axis = rng.normal(size=3)
    angle = np.radians(rng.uniform(30.0, 50.0))
    rotation = Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle)
    direction = rng.normal(size=3)
    offset = direction / np.linalg.norm(direction) * rng.uniform(0.5, 1.5)
    return (rotation * Rotation.from_quat(truth_q)).as_quat(), truth_t + offset


def pose_stream(
    rng: np.random.Generator,
    truth: PoseEstimate,
    count: int,
    covariance: np.ndarray = PNP_COVARIANCE,
    *,
    noise_scale: float = 1.0,
    outliers: float = 0.0,
    motion: Callable[[np.ndarray], np.ndarray] | None = None,
    common: np.ndarray | None = None,
    correlation: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``count`` noisy samples of ``truth``: quaternions, translations and a mask of outliers.

    Noise ``xi ~ N(0, noise_scale^2 covariance)`` as a left perturbation (the stated covariance
    stays ``covariance``: ``noise_scale`` 3 makes it 3x optimistic); a fraction ``outliers``
    replaced by :func:`pnp_flip`; ``motion(k)`` (k the sample indices) gives the true
    ``xi`` of each sample from ``truth`` (drift, jump); ``common``: one error of this
    covariance drawn once and applied to every sample (a static input shared by all);
    ``correlation``: AR(1) noise with this lag-one correlation and the same marginal
    covariance, ``xi_k = correlation xi_(k-1) + sqrt(1 - correlation^2) w_k``.
    """
    base = rigid(truth.rotation, truth.translation)
    if common is not None:
        base = perturb_left(rng.multivariate_normal(np.zeros(6), common), base)
    indices = np.arange(count)
    if motion is not None:
        base = perturb_left(motion(indices), base)
    noise = rng.multivariate_normal(np.zeros(6), noise_scale**2 * covariance, count)
    for k in range(1, count if correlation else 0):
        noise[k] = correlation * noise[k - 1] + math.sqrt(1.0 - correlation**2) * noise[k]
    translations, rotations = perturb_left(noise, base).as_components()
    q, t = np.atleast_2d(rotations.as_quat()), np.atleast_2d(translations)
    flipped = rng.random(count) < outliers
    for k in np.flatnonzero(flipped):
        q[k], t[k] = pnp_flip(rng, q[k], t[k])
    return q, t, flipped


def run(estimator: StaticEstimator, q: np.ndarray, t: np.ndarray, covariance=None) -> StaticState:
    """Feed a whole stream; the last state."""
    state = estimator.state
    for k in range(len(q)):
        state = estimator.add(q[k], t[k], covariance)
    return state


def nees(state: StaticState, truth: PoseEstimate) -> float:
    """Normalised estimation error squared of a pose state against the truth."""
    error = left_error(PoseEstimate(state.rotation, state.translation), truth)
    return float(error @ np.linalg.solve(state.covariance, error))


def nees_interval(
    trials: int, dof: int, level: float = 0.95, nu: int | None = None
) -> tuple[float, float]:
    """Two-sided interval of the mean NEES of ``trials`` consistent estimates: the mean of
    chi-square(dof) variables, or, for a covariance estimated with ``nu`` degrees of freedom
    and unbiased by ``nu / (nu - dof - 1)``, of the scaled Hotelling ``T^2`` (mean ``dof``,
    heavier tails; Anderson 2003, section 5.2) by the normal approximation."""
    tail = (1.0 - level) / 2.0
    if nu is None:
        total = trials * dof
        return stats.chi2.ppf(tail, total) / trials, stats.chi2.ppf(1.0 - tail, total) / trials
    denominator = nu - dof + 1
    scale = (nu - dof - 1) * dof / denominator
    spread = scale * math.sqrt(stats.f.var(dof, denominator) / trials)
    z = stats.norm.ppf(1.0 - tail)
    return dof - z * spread, dof + z * spread


def batch_dof(samples: int) -> int:
    """Degrees of freedom of the estimator's batch-means covariance after ``samples``
    accepted samples: batches less one (module docstring of ``static_estimate``)."""
    size = 1
    while samples > 2 * BATCHES * size:
        size *= 2
    return -(-samples // size) - 1


def nees_experiment(name: str, trials: int, samples: int, **stream) -> list[float]:
    """NEES of the final estimate over seeded trials; ``stream`` as :func:`pose_stream`, plus
    ``with_covariance`` (default True) and ``common_known`` (pass ``common`` to the
    estimator)."""
    rng = rng_for(f"static-nees-{name}")
    with_covariance = stream.pop("with_covariance", True)
    common = stream.get("common")
    values = []
    for _ in range(trials):
        truth = random_truth(rng)
        q, t, _ = pose_stream(rng, truth, samples, **stream)
        estimator = StaticEstimator("pose", common_covariance=common)
        state = run(estimator, q, t, PNP_COVARIANCE if with_covariance else None)
        values.append(nees(state, truth))
    return values


def flip_moves(trials: int, samples: int, outliers: float) -> tuple[float, float]:
    """Largest move of the estimate (in its standard deviations, Mahalanobis) at a flip
    sample, and the fraction of flips rejected."""
    rng = rng_for("static-flips")
    worst, rejected, total = 0.0, 0, 0
    for _ in range(trials):
        truth = random_truth(rng)
        q, t, flipped = pose_stream(rng, truth, samples, outliers=outliers)
        estimator = StaticEstimator("pose")
        before = estimator.state
        for k in range(samples):
            state = estimator.add(q[k], t[k], PNP_COVARIANCE)
            if flipped[k] and before.covariance is not None:
                total += 1
                rejected += state.rejected - before.rejected
                move = left_error(
                    PoseEstimate(state.rotation, state.translation),
                    PoseEstimate(before.rotation, before.translation),
                )
                worst = max(worst, float(move @ np.linalg.solve(before.covariance, move)) ** 0.5)
            before = state
    return worst, rejected / max(total, 1)


def drift(speed: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """A constant-velocity motion: ``xi(k) = k speed / RATE_HZ`` (``speed`` per second)."""
    return lambda k: np.outer(k, speed) / RATE_HZ


def jump(at: int, offset: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """A single jump by ``offset`` (xi) at sample ``at``."""
    return lambda k: np.outer(k >= at, offset)


def detection(name: str, trials: int, samples: int, motion, start: int = 0) -> list[int | None]:
    """Samples from the start of the motion until ``not_static``, per trial (None: never)."""
    rng = rng_for(f"static-motion-{name}")
    delays: list[int | None] = []
    for _ in range(trials):
        truth = random_truth(rng)
        q, t, _ = pose_stream(rng, truth, samples, motion=motion)
        estimator = StaticEstimator("pose")
        delay = None
        for k in range(samples):
            if estimator.add(q[k], t[k], PNP_COVARIANCE).not_static:
                delay = k - start
                break
        delays.append(delay)
    return delays


def false_alarms(runs: int, samples: int, correlation: float = 0.0) -> int:
    """Static runs (1 % flips, AR(1) noise of ``correlation``) that ever report
    ``not_static``."""
    rng = rng_for(f"static-false-alarms-{correlation}" if correlation else "static-false-alarms")
    alarms = 0
    for _ in range(runs):
        truth = random_truth(rng)
        q, t, _ = pose_stream(rng, truth, samples, outliers=0.01, correlation=correlation)
        alarms += run(StaticEstimator("pose"), q, t, PNP_COVARIANCE).not_static
    return alarms


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=500)
    parser.add_argument("--long", type=int, default=100, help="long static runs")
    args = parser.parse_args(argv)
    trials = args.trials
    intervals = {samples: nees_interval(trials, 6, nu=batch_dof(samples)) for samples in (60, 300)}
    results: dict[str, object] = {"trials": trials, "nees_interval_95": intervals}
    print(
        f"mean NEES over {trials} trials, 6 dof, 95 % interval of the mean "
        + ", ".join(f"N={n}: [{low:.2f}, {high:.2f}]" for n, (low, high) in intervals.items())
    )
    common = np.diag([1e-5, 1e-5, 1e-5, 4e-6, 4e-6, 4e-6])
    cases = {
        "honest": {},
        "honest, 3 % flips": {"outliers": 0.03},
        "3x optimistic": {"noise_scale": 3.0},
        "3x optimistic, 3 % flips": {"noise_scale": 3.0, "outliers": 0.03},
        "shared error": {"common": common},
        "no covariance, 3 % flips": {"with_covariance": False, "outliers": 0.03},
        "AR(1) 0.6": {"correlation": 0.6},
        "AR(1) 0.9, 3 % flips": {"correlation": 0.9, "outliers": 0.03},
    }
    for name, stream in cases.items():
        for samples in (60, 300):
            values = nees_experiment(f"{name}-{samples}", trials, samples, **dict(stream))
            mean = float(np.mean(values))
            low, high = intervals[samples]
            verdict = "ok" if low <= mean <= high else "OUT"
            print(f"  {name:28s} N={samples:4d}: {mean:6.2f} {verdict}")
            results[f"nees {name} N={samples}"] = mean
    worst, rejected = flip_moves(trials // 5, 300, 0.05)
    print(f"flips at 5 %: largest move {worst:.3g} std, {100 * rejected:.1f} % rejected")
    results["flip largest move std"], results["flip rejected fraction"] = worst, rejected
    for correlation in (0.0, 0.6, 0.9):
        alarms = false_alarms(args.long, 10_000, correlation)
        print(
            f"false alarms, AR(1) {correlation}: {alarms} of {args.long} static runs of "
            "10,000 samples (1 % flips)"
        )
        results[f"false alarms AR(1) {correlation}"] = [alarms, args.long]
    motions = {
        "drift 5 mm/s": (drift(np.array([0, 0, 0, 0.005, 0, 0])), 0),
        "rotation 2 deg/s": (drift(np.radians([0, 0, 2.0, 0, 0, 0])), 0),
        "jump 2 cm at 200": (jump(200, np.array([0, 0, 0, 0.02, 0, 0])), 200),
        "jump 5 mm at 200": (jump(200, np.array([0, 0, 0, 0.005, 0, 0])), 200),
    }
    for name, (motion, start) in motions.items():
        delays = detection(name, trials // 5, 1000, motion, start)
        found = [d for d in delays if d is not None]
        text = f"median {np.median(found):.0f}, max {max(found)}" if found else "never"
        print(f"  {name:18s}: detected in {len(found)}/{len(delays)}, samples: {text}")
        results[f"detection {name}"] = delays
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
