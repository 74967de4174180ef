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


def test_late_measurements_give_the_in_order_result():
    rng = rng_for("pose-filter-late")
    schedule = two_trackers(1.0)
    truth = walk(rng, [t for t, _ in schedule], 1.0, 1.0)
    measurements = []
    for t_ns, cov in schedule:
        q, t = measure(rng, truth(t_ns), cov)
        measurements.append((t_ns, q, t, cov))
    in_order, shuffled = PoseKalmanFilter(1.0, 1.0), PoseKalmanFilter(1.0, 1.0)
    for m in measurements:
        assert in_order.update(*m) in ("updated", "restarted")
    order = list(range(len(measurements)))
    for i in range(1, len(order) - 3, 4):  # every fourth arrives three places late
        order[i : i + 4] = [*order[i + 1 : i + 4], order[i]]
    outcomes = [shuffled.update(*measurements[i]) for i in order]
    assert outcomes.count("late") == len(range(1, len(order) - 3, 4))
    for t_ns in (measurements[-1][0], measurements[-1][0] + 20 * MS):
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
