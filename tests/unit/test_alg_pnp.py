import numpy as np
import pytest
from scipy.stats import chi2

from bench.pnp_ambiguity_bench import target, view
from bench.synthetic import CAMERA_MATRIX, left_error, random_quaternion, rng_for, rotation_error
from ubitrack_agent.services.algorithms.estimate import PoseEstimate
from ubitrack_agent.services.algorithms.pnp import (
    AmbiguousPose,
    choose_method,
    project,
    solve_pnp,
    solve_pnp_ransac,
)


def _scene(name: str, object_points: np.ndarray):
    rng = rng_for(name)
    pose = PoseEstimate(random_quaternion(rng), np.array([0.05, -0.03, 1.0]))
    return rng, pose, project(object_points, pose, CAMERA_MATRIX)


def _cube(rng, n):
    return rng.uniform(-0.1, 0.1, (n, 3))


def _grid():
    x, y = np.meshgrid(np.arange(7) * 0.03, np.arange(5) * 0.03)
    return np.column_stack((x.ravel(), y.ravel(), np.zeros(x.size)))


SQUARE = 0.05 * np.array([[-1, 1, 0], [1, 1, 0], [1, -1, 0], [-1, -1, 0.0]])


@pytest.mark.parametrize(
    ("points", "expected"),
    [(_cube(rng_for("cube"), 8), "sqpnp"), (_grid(), "ippe"), (SQUARE, "ippe_square")],
)
def test_method_is_chosen_by_geometry(points, expected):
    assert choose_method(points) == expected


@pytest.mark.parametrize("points", [_cube(rng_for("pnp-cube"), 8), _grid(), SQUARE])
def test_noise_free_recovers_ground_truth(points):
    _, pose, pixels = _scene("pnp-exact", points)
    est = solve_pnp(points, pixels, CAMERA_MATRIX)
    assert rotation_error(est.rotation, pose.rotation) < 1e-9
    np.testing.assert_allclose(est.translation, pose.translation, atol=1e-9)


@pytest.mark.parametrize("method", ["sqpnp", "epnp", "iterative"])
def test_explicit_methods_on_general_points(method):
    points = _cube(rng_for("pnp-methods"), 10)
    _, pose, pixels = _scene("pnp-methods", points)
    est = solve_pnp(points, pixels, CAMERA_MATRIX, method=method)
    assert rotation_error(est.rotation, pose.rotation) < 1e-8


def test_distortion_is_modelled():
    points = _cube(rng_for("pnp-dist"), 12)
    _, pose, _ = _scene("pnp-dist", points)
    dist = np.array([-0.2, 0.05, 0.001, -0.001, 0.0])
    pixels = project(points, pose, CAMERA_MATRIX, dist)
    est = solve_pnp(points, pixels, CAMERA_MATRIX, dist)
    np.testing.assert_allclose(est.translation, pose.translation, atol=1e-9)


def test_covariance_matches_monte_carlo_spread():
    points = _cube(rng_for("pnp-mc"), 10)
    rng, pose, pixels = _scene("pnp-mc", points)
    sigma = 1.0
    predicted = solve_pnp(points, pixels, CAMERA_MATRIX, pixel_sigma=sigma).covariance
    errors = []
    for _ in range(200):
        est = solve_pnp(points, pixels + rng.normal(0, sigma, pixels.shape), CAMERA_MATRIX)
        errors.append(left_error(est, pose))
    ratio = np.diag(np.cov(np.array(errors).T)) / np.diag(predicted)
    assert np.all((ratio > 0.65) & (ratio < 1.5)), ratio


def test_covariance_from_each_pixels_covariance_is_consistent():
    """Pixels whose noise differs point by point and axis by axis: the covariance from their
    own covariances (the sandwich of the unweighted estimate) has mean NEES within the
    chi-square interval of 300 poses; the residuals' estimate from five points does not."""
    rng = rng_for("pnp-pixel-covariances")
    points = _cube(rng, 5)
    sigmas = rng.uniform(0.2, 1.5, (5, 2))
    covariances = np.array([np.diag(s**2) for s in sigmas])
    given, estimated = [], []
    for _ in range(300):
        pose = PoseEstimate(random_quaternion(rng), np.array([0.05, -0.03, 1.0]))
        pixels = project(points, pose, CAMERA_MATRIX) + rng.normal(0.0, sigmas)
        for nees, options in ((given, {"pixel_covariances": covariances}), (estimated, {})):
            est = solve_pnp(points, pixels, CAMERA_MATRIX, **options)
            error = left_error(est, pose)
            nees.append(error @ np.linalg.solve(est.covariance, error))
    low, high = chi2.ppf([0.005, 0.995], 6 * 300) / 300
    assert low < np.mean(given) < high
    assert np.mean(estimated) > high


def test_equal_pixel_covariances_give_the_covariance_of_pixel_sigma():
    points = _cube(rng_for("pnp-equal"), 8)
    _, _, pixels = _scene("pnp-equal", points)
    by_sigma = solve_pnp(points, pixels, CAMERA_MATRIX, pixel_sigma=0.7).covariance
    each = np.array([np.eye(2) * 0.49] * 8)
    by_covariances = solve_pnp(points, pixels, CAMERA_MATRIX, pixel_covariances=each).covariance
    np.testing.assert_allclose(by_covariances, by_sigma, rtol=1e-9)
    with pytest.raises(ValueError, match="pixel_covariances"):
        solve_pnp(points, pixels, CAMERA_MATRIX, pixel_covariances=each[:3])


def test_four_points_of_a_nearly_planar_target_are_decided_or_refused():
    """The figure-1 target with one feature hidden: without the check some poses are tens of
    degrees off (the other minimum); with the pixel noise known, none is more than 20 degrees
    off, few more than 10 (the data's own bad luck: the truth fits worse), and few are refused."""
    features, sigma = target()
    rng = rng_for("pnp-ambiguity")
    plain_errors, errors, refused = [], [], 0
    for _ in range(300):
        truth = view(rng)
        points = features[np.sort(rng.choice(5, 4, replace=False))]
        pixels = project(points, truth, CAMERA_MATRIX) + rng.normal(0.0, sigma, (4, 2))
        plain = solve_pnp(points, pixels, CAMERA_MATRIX)
        plain_errors.append(np.degrees(rotation_error(plain.rotation, truth.rotation)))
        try:
            estimate = solve_pnp(points, pixels, CAMERA_MATRIX, pixel_sigma=sigma)
        except AmbiguousPose:
            refused += 1
            continue
        errors.append(np.degrees(rotation_error(estimate.rotation, truth.rotation)))
    plain_errors, errors = np.array(plain_errors), np.array(errors)
    assert np.sum(plain_errors > 20) > 0 and np.sum(errors > 20) == 0
    assert np.sum(errors > 10) <= np.sum(plain_errors > 10) / 3
    assert 0 < refused < 30


def test_ransac_rejects_outliers():
    points = _cube(rng_for("pnp-ransac"), 60)
    rng, pose, pixels = _scene("pnp-ransac", points)
    noisy = pixels + rng.normal(0, 0.5, pixels.shape)
    outliers = rng.choice(60, 12, replace=False)
    noisy[outliers] = rng.uniform(0, 640, (12, 2))
    est, inliers = solve_pnp_ransac(points, noisy, CAMERA_MATRIX)
    assert not inliers[outliers].any()
    assert rotation_error(est.rotation, pose.rotation) < np.radians(0.5)
    assert np.linalg.norm(est.translation - pose.translation) < 0.01


@pytest.mark.parametrize(
    ("obj", "img", "kwargs", "message"),
    [
        (np.zeros((2, 3)), np.zeros((2, 2)), {}, "at least 3"),
        (np.zeros((5, 3)), np.zeros((5, 3)), {}, "shape"),
        (np.full((5, 3), np.nan), np.zeros((5, 2)), {}, "NaN"),
        (np.zeros((5, 3)), np.zeros((6, 2)), {}, "same number"),
        (np.outer(np.arange(5.0), [1, 1, 1]), np.zeros((5, 2)), {}, "collinear"),
        (_grid()[[0, 1, 7]], np.zeros((3, 2)), {"method": "ippe"}, "at least 4"),
        (_cube(rng_for("x"), 6), np.zeros((6, 2)), {"method": "ippe"}, "coplanar"),
        (_cube(rng_for("x"), 6), np.zeros((6, 2)), {"method": "posit"}, "unknown"),
    ],
)
def test_bad_input_raises_value_error(obj, img, kwargs, message):
    with pytest.raises(ValueError, match=message):
        solve_pnp(obj, img, CAMERA_MATRIX, **kwargs)


def test_bad_camera_matrix_raises():
    with pytest.raises(ValueError, match="camera_matrix"):
        solve_pnp(_grid(), np.zeros((35, 2)), np.eye(3) * -1)
