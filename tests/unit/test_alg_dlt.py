import numpy as np
import pytest

from bench.synthetic import CAMERA_MATRIX, random_quaternion, rng_for
from ubitrack_agent.services.algorithms.auxiliary import compose_projection
from ubitrack_agent.services.algorithms.dlt import homogeneous, projection_dlt
from ubitrack_agent.services.algorithms.estimate import PoseEstimate

PLANE = np.column_stack((np.arange(8.0), np.arange(8.0) ** 2, np.zeros(8)))


def _apply(projection, points):
    image = homogeneous(points) @ projection.T
    return image[:, :2] / image[:, 2:]


def _scene(name, n):
    rng = rng_for(name)
    pose = PoseEstimate(random_quaternion(rng), np.array([0.1, -0.05, 3.0]))
    truth = compose_projection(CAMERA_MATRIX, pose)
    points = rng.uniform(-0.5, 0.5, (n, 3))
    return rng, truth, points, _apply(truth, points)


@pytest.mark.parametrize("refine", [False, True])
def test_noise_free_recovers_projection(refine):
    _, truth, points, pixels = _scene("dlt-exact", 6)
    np.testing.assert_allclose(projection_dlt(points, pixels, refine=refine), truth, atol=1e-8)


def test_refinement_does_not_increase_held_out_error():
    rng, truth, points, pixels = _scene("dlt-noisy", 20)
    held_out = rng.uniform(-0.5, 0.5, (200, 3))
    errors = {False: [], True: []}
    for _ in range(30):
        noisy = pixels + rng.normal(0, 1.0, pixels.shape)
        for refine in errors:
            estimate = projection_dlt(points, noisy, refine=refine)
            errors[refine].append(
                np.mean((_apply(estimate, held_out) - _apply(truth, held_out)) ** 2)
            )
    linear, refined = (np.sqrt(np.mean(errors[r])) for r in (False, True))
    assert refined <= linear * 1.001
    assert 0.3 < refined < 1.5  # about sigma * sqrt(11 / N) for a well spread rig


@pytest.mark.parametrize(
    ("points", "pixels", "message"),
    [
        (np.zeros((5, 3)), np.zeros((5, 2)), "at least 6"),
        (np.zeros((8, 2)), np.zeros((8, 2)), "shape"),
        (np.full((8, 3), np.inf), np.zeros((8, 2)), "NaN"),
        (
            np.column_stack((np.ones((8, 2)) * np.arange(8)[:, None] ** [1, 2], np.zeros(8))),
            np.ones((8, 2)),
            "coplanar",
        ),
    ],
)
def test_bad_input_raises_value_error(points, pixels, message):
    with pytest.raises(ValueError, match=message):
        projection_dlt(points, pixels)
