import cv2
import numpy as np
import pytest

from bench.synthetic import camera_ring, observe_points, rng_for
from ubitrack_agent.services.algorithms.triangulation import triangulate_points


@pytest.mark.parametrize("n_views", [2, 3, 5])
@pytest.mark.parametrize("refine", [False, True])
def test_noise_free_recovers_points(n_views, refine):
    points = rng_for("tri-exact").uniform(-0.3, 0.3, (20, 3))
    projections = camera_ring(n_views)
    result = triangulate_points(projections, observe_points(projections, points), refine=refine)
    np.testing.assert_allclose(result.points, points, atol=1e-9)


def test_two_views_agree_with_opencv_linear_triangulation():
    rng = rng_for("tri-opencv")
    points = rng.uniform(-0.3, 0.3, (30, 3))
    projections = camera_ring(2)
    pixels = observe_points(projections, points) + rng.normal(0, 1.0, (2, 30, 2))
    ours = triangulate_points(projections, pixels, refine=False).points
    theirs = cv2.triangulatePoints(projections[0], projections[1], pixels[0].T, pixels[1].T)
    np.testing.assert_allclose(ours, (theirs[:3] / theirs[3]).T, atol=2e-4)


def test_refinement_reduces_reprojection_error_and_covariance_matches_spread():
    rng = rng_for("tri-noisy")
    projections = camera_ring(3)
    point = np.array([[0.1, -0.05, 0.02]])
    truth = observe_points(projections, point)
    sigma = 1.0
    errors, linear_residual, refined_residual = [], 0.0, 0.0
    for _ in range(200):
        pixels = truth + rng.normal(0, sigma, truth.shape)
        linear = triangulate_points(projections, pixels, refine=False).points
        refined = triangulate_points(projections, pixels, pixel_sigma=sigma)
        linear_residual += np.sum((observe_points(projections, linear) - pixels) ** 2)
        refined_residual += np.sum((observe_points(projections, refined.points) - pixels) ** 2)
        errors.append(refined.points[0] - point[0])
    assert refined_residual <= linear_residual
    ratio = np.diag(np.cov(np.array(errors).T)) / np.diag(refined.covariances[0])
    assert np.all((ratio > 0.7) & (ratio < 1.4)), ratio


@pytest.mark.parametrize(
    ("projections", "pixels", "message"),
    [
        (camera_ring(2)[:1], np.zeros((1, 3, 2)), "at least 2 views"),
        (camera_ring(2), np.zeros((3, 3, 2)), "shape"),
        (camera_ring(2), np.zeros((2, 0, 2)), "at least 1 point"),
        (camera_ring(2), np.full((2, 3, 2), np.nan), "NaN"),
        (np.stack((camera_ring(2)[0], 2 * camera_ring(2)[0])), np.zeros((2, 3, 2)), "one centre"),
    ],
)
def test_bad_input_raises_value_error(projections, pixels, message):
    with pytest.raises(ValueError, match=message):
        triangulate_points(projections, pixels)
