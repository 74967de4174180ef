"""The asynchronous pose filter: tracking, out-of-order re-filtering, gating, and the
consistency of its covariance (NEES over Monte Carlo runs of its own motion model)."""

import numpy as np
import pytest
from scipy import stats

from bench.synthetic import left_error, random_quaternion, rng_for
from ubitrack_agent.core import quaternions
from ubitrack_agent.core.errors import ExtrapolationError, NoDataError
from ubitrack_agent.services.algorithms.estimate import PoseEstimate
from ubitrack_agent.services.algorithms.pose_filter import PoseKalmanFilter

SECOND = 1_000_000_000
MS = 1_000_000
COV_A = np.diag([np.radians(0.05) ** 2] * 3 + [0.5e-3**2] * 3)
COV_B = np.diag([np.radians(0.3) ** 2] * 2 + [np.radians(0.02) ** 2] + [2e-3**2] * 2 + [0.3e-3**2])
STATIC_A = np.diag([np.radians(0.05) ** 2] * 3 + [0.5e-3**2] * 3)
"""Tracker A's static error (a calibration's), as large as its white noise."""


def walk(rng: np.random.Generator, times_ns, angular: float, linear: float):
    """Truth drawn from the filter's own model at ``times_ns``: white angular and linear
    acceleration of densities ``angular``, ``linear``, each (angle, rate) and (position,
    velocity) pair advanced by the exact discrete transition and noise of the integrated white
    noise; returns ``pose(t_ns)``."""
    q, p = random_quaternion(rng), rng.uniform(-1, 1, 3)
    omega, velocity = rng.normal(0, 0.3, 3), rng.normal(0, 0.2, 3)
    times = sorted(set(times_ns))
    poses, previous = {times[0]: PoseEstimate(q, p)}, times[0]
    for t_ns in times[1:]:
        dt = (t_ns - previous) * 1e-9
        block = np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
        turn = omega * dt
        for density, (value, rate) in ((angular, (turn, omega)), (linear, (p, velocity))):
            noise = rng.normal(size=(3, 2)) @ np.linalg.cholesky(density * block).T
            if value is p:
                p = p + velocity * dt + noise[:, 0]
            else:
                turn = turn + noise[:, 0]
            rate += noise[:, 1]
        q = quaternions.multiply(quaternions.from_rotvec(turn), q)
        poses[t_ns], previous = PoseEstimate(q, p), t_ns
    return poses.__getitem__


def measure(rng, truth: PoseEstimate, covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``Exp(xi) T_true`` with ``xi ~ N(0, covariance)``, to first order in ``xi`` (the
    covariances here are diagonal; scipy's exact form costs a millisecond per pose)."""
    xi = rng.normal(size=6) * np.sqrt(np.diag(covariance))
    turn = quaternions.from_rotvec(xi[:3])
    return quaternions.multiply(turn, truth.rotation), (
        quaternions.rotate(turn, truth.translation) + xi[3:]
    )


def two_trackers(seconds: float) -> list[tuple[int, np.ndarray]]:
    """Tracker A at 60 Hz and tracker B at 30 Hz, a third of a frame apart."""
    a = [(k * SECOND // 60, COV_A) for k in range(int(60 * seconds))]
    b = [(k * SECOND // 30 + 11 * MS, COV_B) for k in range(int(30 * seconds))]
    return sorted(a + b, key=lambda item: item[0])


def nees(estimate: PoseEstimate, truth: PoseEstimate) -> float:
    error = left_error(estimate, truth)
    return float(error @ np.linalg.solve(estimate.covariance, error))


def test_covariance_is_consistent_posterior_and_20_ms_ahead():
    """Mean NEES over 100 runs of the model's own motion within the chi-square 99 % interval,
    for the posterior and for the prediction 20 ms ahead, with B's measurements arriving late
    (after the next A measurement), as a camera's do."""
    rng = rng_for("pose-filter-nees")
    angular, linear = 0.5, 0.5
    runs, posterior, ahead = 100, [], []
    for _ in range(runs):
        schedule = two_trackers(1.0)
        newest = schedule[-1][0]
        truth = walk(rng, [t for t, _ in schedule] + [newest + 20 * MS], angular, linear)
        kalman = PoseKalmanFilter(angular, linear)
        arrivals = list(schedule)
        for i in range(len(arrivals) - 1):  # B arrives after the following A
            if arrivals[i][1] is COV_B:
                arrivals[i], arrivals[i + 1] = arrivals[i + 1], arrivals[i]
        for t_ns, cov in arrivals:
            q, t = measure(rng, truth(t_ns), cov)
            kalman.update(t_ns, q, t, cov)
        posterior.append(nees(kalman.estimate(newest), truth(newest)))
        ahead.append(nees(kalman.estimate(newest + 20 * MS), truth(newest + 20 * MS)))
    low, high = stats.chi2.ppf([0.005, 0.995], 6 * runs) / runs
    assert low < np.mean(posterior) < high
    assert low < np.mean(ahead) < high


@pytest.mark.parametrize("considered", [False, True])
def test_late_measurements_give_the_in_order_result(considered: bool):
    """Re-filtered late measurements give the in-order result; ``considered``: with static
    parts, tracker A's and B's static errors considered (two sources)."""
    rng = rng_for(f"pose-filter-late-{considered}")
    schedule = two_trackers(1.0)
    truth = walk(rng, [t for t, _ in schedule], 1.0, 1.0)
    measurements = []
    for t_ns, cov in schedule:
        static = {}
        if considered:
            a = cov is COV_A
            static = {"static": STATIC_A if a else 0.2 * cov, "source": "A" if a else "B"}
            cov = cov + STATIC_A if a else cov
        q, t = measure(rng, truth(t_ns), cov)
        measurements.append(((t_ns, q, t, cov), static))
    in_order, shuffled = PoseKalmanFilter(1.0, 1.0), PoseKalmanFilter(1.0, 1.0)
    for values, static in measurements:
        assert in_order.update(*values, **static) in ("updated", "restarted")
    order = list(range(len(measurements)))
    for i in range(1, len(order) - 3, 4):  # every fourth arrives three places late
        order[i : i + 4] = [*order[i + 1 : i + 4], order[i]]
    outcomes = [shuffled.update(*measurements[i][0], **measurements[i][1]) for i in order]
    assert outcomes.count("late") == len(range(1, len(order) - 3, 4))
    newest = measurements[-1][0][0]
    for t_ns in (newest, newest + 20 * MS):
        a, b = in_order.estimate(t_ns), shuffled.estimate(t_ns)
        np.testing.assert_allclose(b.translation, a.translation, atol=1e-12)
        assert abs(abs(b.rotation @ a.rotation) - 1) < 1e-12
        np.testing.assert_allclose(b.covariance, a.covariance, rtol=1e-8, atol=1e-20)


def test_measurement_older_than_the_window_changes_nothing():
    kalman = PoseKalmanFilter(1.0, 1.0, window_ns=50 * MS)
    for k in range(10):
        kalman.update(k * 20 * MS, quaternions.IDENTITY, np.zeros(3), COV_A)
    before = kalman.estimate(180 * MS)
    assert kalman.update(100 * MS, quaternions.IDENTITY, np.ones(3), COV_A) == "too_old"
    after = kalman.estimate(180 * MS)
    np.testing.assert_array_equal(after.translation, before.translation)


def test_flipped_pose_is_gated_and_does_not_move_the_output():
    """A 2D-3D PnP flip (180 degrees about the optical axis) is refused by the innovation
    gate; only several in a row (the target is really there) restart the filter."""
    rng = rng_for("pose-filter-flip")
    schedule = two_trackers(1.0)
    truth = walk(rng, [t for t, _ in schedule], 1.0, 1.0)
    kalman = PoseKalmanFilter(1.0, 1.0)
    for t_ns, cov in schedule[:-1]:
        kalman.update(t_ns, *measure(rng, truth(t_ns), cov), cov)
    t_ns = schedule[-1][0]
    before = kalman.estimate(t_ns)
    q, t = measure(rng, truth(t_ns), COV_B)
    flipped = quaternions.multiply(q, quaternions.from_rotvec(np.array([0, 0, np.pi])))
    assert kalman.update(t_ns, flipped, t, COV_B) == "gated"
    after = kalman.estimate(t_ns)
    np.testing.assert_array_equal(after.translation, before.translation)
    np.testing.assert_array_equal(after.rotation, before.rotation)
    outcomes = [
        kalman.update(t_ns + k * MS, flipped, t, COV_B)
        for k in range(1, kalman.settings.restart_after)
    ]
    assert outcomes[-1] == "restarted" and set(outcomes[:-1]) == {"gated"}
    assert abs(abs(kalman.estimate(t_ns + len(outcomes) * MS).rotation @ flipped) - 1) < 1e-9


def test_prediction_beats_the_latest_measurement_on_a_smooth_walk():
    rng = rng_for("pose-filter-ahead")
    schedule = two_trackers(1.0)
    display = schedule[-1][0] + 20 * MS
    truth = walk(rng, [t for t, _ in schedule] + [display], 0.01, 0.01)
    kalman = PoseKalmanFilter(0.01, 0.01)
    for t_ns, cov in schedule:
        q, t = measure(rng, truth(t_ns), cov)
        kalman.update(t_ns, q, t, cov)
    predicted = left_error(kalman.estimate(display), truth(display))
    held = left_error(PoseEstimate(q, t), truth(display))
    assert np.linalg.norm(predicted[3:]) < np.linalg.norm(held[3:])


def test_bounds_and_bad_input():
    kalman = PoseKalmanFilter(1.0, 1.0)
    with pytest.raises(NoDataError):
        kalman.estimate(0)
    assert kalman.update(10 * MS, quaternions.IDENTITY, np.zeros(3), COV_A) == "restarted"
    with pytest.raises(ExtrapolationError, match="ahead"):
        kalman.estimate(10 * MS + kalman.settings.max_ahead_ns + 1)
    with pytest.raises(ExtrapolationError):
        kalman.estimate(5 * MS)
    assert kalman.update(10 * MS + SECOND, quaternions.IDENTITY, np.ones(3), COV_A) == "restarted"
    with pytest.raises(ValueError, match="unit quaternion"):
        kalman.update(2 * SECOND, [0, 0, 0, 2.0], np.zeros(3), COV_A)
    with pytest.raises(ValueError, match="positive definite"):
        kalman.update(2 * SECOND, quaternions.IDENTITY, np.zeros(3), -COV_A)
    with pytest.raises(ValueError, match="angular_noise"):
        PoseKalmanFilter(angular_noise=-1.0, linear_noise=1.0)


def perturbed(truth: PoseEstimate, xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``Exp(xi) T_true`` to first order in ``xi``."""
    turn = quaternions.from_rotvec(xi[:3])
    return quaternions.multiply(turn, truth.rotation), quaternions.rotate(
        turn, truth.translation
    ) + xi[3:]


def static_runs(rng, runs: int, seconds: float, density: float, filters):
    """Final NEES of each filter in ``filters`` (name -> (factory, told the static part)) over
    ``runs`` runs of the model's own motion (``density``), tracker A's samples sharing one
    static error per run drawn from :data:`STATIC_A` (announced as part of their covariance)."""
    final: dict[str, list[float]] = {name: [] for name in filters}
    for _ in range(runs):
        schedule = two_trackers(seconds)
        newest = schedule[-1][0]
        truth = walk(rng, [t for t, _ in schedule], density, density)
        bias = rng.normal(size=6) * np.sqrt(np.diag(STATIC_A))
        made = {name: (make(), told) for name, (make, told) in filters.items()}
        for t_ns, cov in schedule:
            xi = rng.normal(size=6) * np.sqrt(np.diag(cov))
            a = cov is COV_A
            q, t = perturbed(truth(t_ns), xi + bias if a else xi)
            whole = cov + STATIC_A if a else cov
            for kalman, told in made.values():
                static = {"static": STATIC_A, "source": "A"} if told and a else {}
                kalman.update(t_ns, q, t, whole, **static)
        for name, (kalman, _) in made.items():
            final[name].append(nees(kalman.estimate(newest), truth(newest)))
    return {name: float(np.mean(values)) for name, values in final.items()}


def test_a_considered_static_error_keeps_the_covariance_consistent():
    """Tracker A's samples share one static error per run: the filter told so (the static
    error considered, Schmidt-Kalman) is consistent over 100 runs (mean NEES of the final
    posterior within the chi-square 99 % interval of independent runs); the same filter taking
    the whole covariance as white noise averages the static error away and is over-confident
    (a slow motion: it averages over many samples)."""
    rng = rng_for("pose-filter-consider")
    runs, density = 100, 0.005
    means = static_runs(
        rng,
        runs,
        1.0,
        density,
        {
            "considered": (lambda: PoseKalmanFilter(density, density), True),
            "white": (lambda: PoseKalmanFilter(density, density), False),
        },
    )
    low, high = stats.chi2.ppf([0.005, 0.995], 6 * runs) / runs
    assert low < means["considered"] < high
    assert means["white"] > high


def test_adaptive_noise_scales_down_to_the_motion_and_stays_consistent():
    """Configured with ten times the motion's process noise and adaptive, the filter scales
    both densities down (towards a tenth: below half within 4 s) and stays consistent over 30
    runs, tracker A's static error considered."""
    rng = rng_for("pose-filter-adaptive")
    runs = 30
    adaptive: list[PoseKalmanFilter] = []

    def made_adaptive() -> PoseKalmanFilter:
        adaptive.append(PoseKalmanFilter(0.5, 0.5, adaptive=True))
        return adaptive[-1]

    means = static_runs(rng, runs, 4.0, 0.05, {"adaptive": (made_adaptive, True)})
    low, high = stats.chi2.ppf([0.005, 0.995], 6 * runs) / runs
    assert low < means["adaptive"] < high
    scales = np.array([kalman.noise_scales for kalman in adaptive])
    assert np.all(np.exp(np.log(scales).mean(axis=0)) < 0.5)


def test_adaptive_noise_falls_no_lower_than_its_floor_for_inputs_that_over_claim():
    """Exact measurements that claim a covariance make the innovations small: the adaptive
    noise falls, but no lower than ``min_noise_scale`` (without it, far below)."""
    schedule = two_trackers(4.0)
    truth = walk(rng_for("pose-filter-floor"), [t for t, _ in schedule], 0.05, 0.05)
    floored = PoseKalmanFilter(0.5, 0.5, adaptive=True, min_noise_scale=0.25)
    free = PoseKalmanFilter(0.5, 0.5, adaptive=True)
    for t_ns, cov in schedule:
        exact = truth(t_ns)
        for kalman in (floored, free):
            kalman.update(t_ns, exact.rotation, exact.translation, cov)
    assert min(free.noise_scales) < 0.1
    assert min(floored.noise_scales) == pytest.approx(0.25)
    with pytest.raises(ValueError, match="min_noise_scale"):
        PoseKalmanFilter(0.5, 0.5, min_noise_scale=0.0)


def test_a_static_part_larger_than_the_covariance_is_refused():
    kalman = PoseKalmanFilter(1.0, 1.0)
    with pytest.raises(ValueError, match="no larger than the covariance"):
        kalman.update(0, quaternions.IDENTITY, np.zeros(3), COV_A, static=2 * COV_A, source="A")
    whole_static = kalman.update(
        0, quaternions.IDENTITY, np.zeros(3), COV_A, static=COV_A, source="A"
    )
    assert whole_static == "restarted"  # every edge static: no white part, still a measurement
    assert (
        kalman.update(10 * MS, quaternions.IDENTITY, np.zeros(3), COV_A, static=COV_A, source="A")
        == "updated"
    )


@pytest.mark.parametrize(
    ("static", "message"),
    [
        (COV_A + np.triu(np.full((6, 6), 1e-8), 1), "not symmetric"),
        (np.full((6, 6), np.nan), "NaN"),
        (-0.5 * COV_A, "positive semi-definite"),
        (np.zeros((3, 3)), "static"),
    ],
)
def test_a_malformed_static_part_is_refused_and_changes_nothing(static, message):
    kalman = PoseKalmanFilter(1.0, 1.0)
    assert kalman.update(0, quaternions.IDENTITY, np.zeros(3), COV_A) == "restarted"
    with pytest.raises(ValueError, match=message):
        kalman.update(10 * MS, quaternions.IDENTITY, np.ones(3), COV_A, static=static, source="A")
    assert kalman.timestamp_ns == 0  # refused whole: no source considered, no update
    assert kalman.update(20 * MS, quaternions.IDENTITY, np.zeros(3), COV_A) == "updated"


def test_adaptive_noise_learns_from_each_late_measurement_once():
    """Every fourth measurement three places late: the re-filtered ones are not learnt from
    again, so the noise's factors end near the in-order filter's (0.80-1.02 of them over six
    seeds; learning from each replay too, 0.46-0.74: each late one replays three)."""
    rng = rng_for("pose-filter-adaptive-late")
    schedule = two_trackers(4.0)
    truth = walk(rng, [t for t, _ in schedule], 0.05, 0.05)
    measurements = [(t_ns, *measure(rng, truth(t_ns), cov), cov) for t_ns, cov in schedule]
    in_order = PoseKalmanFilter(0.5, 0.5, adaptive=True)
    shuffled = PoseKalmanFilter(0.5, 0.5, adaptive=True)
    for m in measurements:
        in_order.update(*m)
    order = list(range(len(measurements)))
    for i in range(1, len(order) - 3, 4):
        order[i : i + 4] = [*order[i + 1 : i + 4], order[i]]
    for i in order:
        shuffled.update(*measurements[i])
    ratios = np.array(shuffled.noise_scales) / np.array(in_order.noise_scales)
    assert np.all((ratios > 0.75) & (ratios < 1.33)), ratios
    assert max(in_order.noise_scales) < 0.5  # it did learn: a tenth of the motion's noise


@pytest.mark.parametrize("rewires", [3, 12])
def test_sources_beyond_the_bound_leave_the_estimates_as_they_were(rewires: int):
    """A fusion rewired again and again (a new input key, so a new source, each time) keeps
    at most ``max_sources`` static errors considered: a source no kept measurement came from
    is dropped (marginalised), which leaves every estimate as a filter that kept them all
    gives it (a source not observed again does not enter the state's gain)."""
    rng = rng_for(f"pose-filter-sources-{rewires}")
    bounded = PoseKalmanFilter(0.5, 0.5, max_sources=2)
    unbounded = PoseKalmanFilter(0.5, 0.5, max_sources=100)
    t = 0
    for rewire in range(rewires):
        for step in range(30):  # 300 ms per flow: beyond the 200 ms window
            t += 10 * MS
            tracker = "A" if step % 2 else f"flow {rewire}"  # A stays, the other is replaced
            cov = COV_A if step % 2 else COV_B
            static = {"static": 0.5 * cov, "source": tracker}
            q = quaternions.multiply(quaternions.from_rotvec(rng.normal(0, 1e-3, 3)), [0, 0, 0, 1])
            p = rng.normal(0, 1e-3, 3)
            outcomes = [f.update(t, q, p, cov, **static) for f in (bounded, unbounded)]
            assert outcomes[0] == outcomes[1]
            mine, theirs = bounded.estimate(t), unbounded.estimate(t)
            np.testing.assert_allclose(mine.rotation, theirs.rotation, atol=1e-12)
            np.testing.assert_allclose(mine.translation, theirs.translation, atol=1e-12)
            np.testing.assert_allclose(mine.covariance, theirs.covariance, rtol=1e-9, atol=1e-18)
    assert len(bounded._statics) == 2 and len(unbounded._statics) == rewires + 1
