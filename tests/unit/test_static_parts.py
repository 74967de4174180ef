"""A pose's static part (``ErrorPose.static_covariance``, issue 29): carried through the
data path's maths as a claim about the static edges' errors alone (Monte Carlo), on the wire,
and considered by the fusion (its calibration's error not averaged away)."""

import numpy as np
import pytest

from bench.synthetic import perturb_with_covariances, random_quaternion, rng_for
from ubitrack_agent.core import ErrorPose, Pose, decode, encode
from ubitrack_agent.core.measurements import WORKER
from ubitrack_agent.core.poses import (
    compose_poses,
    interpolate_pose,
    invert_pose,
    with_static_error,
)
from ubitrack_agent.net.spec import InputBinding, SpecError, parse_bindings
from ubitrack_agent.services.algorithms.estimate import left_residuals, rigid
from ubitrack_agent.services.registry import lookup

MS = 1_000_000
CALIBRATION = np.diag([np.radians(0.1) ** 2] * 3 + [0.4e-3**2] * 3)
"""A calibration's error: 0.1 degrees and 0.4 mm (the demo's ``C -> HT``)."""
TRACKER = np.diag([np.radians(0.05) ** 2] * 3 + [0.3e-3**2] * 3)
DRAWS = 4000


def _pose(rng: np.random.Generator, t: int, covariance: np.ndarray) -> ErrorPose:
    return ErrorPose(t, random_quaternion(rng), rng.uniform(-1, 1, 3), covariance)


def _exact(pose: ErrorPose) -> Pose:
    return Pose(pose.timestamp_ns, pose.rotation, pose.translation)


@pytest.mark.parametrize("operation", ["chain", "inverse", "interpolation"])
def test_the_static_part_is_the_covariance_of_the_static_errors_alone(operation: str):
    """Draw only the static edges' errors (the tracker's pose exact), run the operation, and
    the results' spread about the mean is the result's static part (Monte Carlo, 4,000 draws:
    each variance within 12 %); the whole covariance is larger by the tracker's share."""
    rng = rng_for(f"static-part-{operation}")
    calibration = with_static_error(_pose(rng, 0, CALIBRATION))
    survey = with_static_error(_pose(rng, 0, 0.5 * CALIBRATION))
    tracker = _pose(rng, 0, TRACKER)
    later = ErrorPose(10 * MS, tracker.rotation, tracker.translation + 0.01, TRACKER)

    def run(calibration_value: Pose, survey_value: Pose) -> Pose | ErrorPose:
        if operation == "chain":  # C -> A = C->HT . (ART->HT)^-1 . ART->WT
            return compose_poses(
                calibration_value, compose_poses(invert_pose(tracker), survey_value)
            )
        if operation == "inverse":
            return invert_pose(compose_poses(calibration_value, tracker))
        before = compose_poses(calibration_value, tracker)
        return interpolate_pose(before, compose_poses(calibration_value, later), 4 * MS)

    result = run(calibration, survey)
    assert isinstance(result, ErrorPose) and result.static_covariance is not None
    draws = [
        perturb_with_covariances(
            rng,
            np.tile(edge.rotation, (DRAWS, 1)),
            np.tile(edge.translation, (DRAWS, 1)),
            np.broadcast_to(edge.covariance, (DRAWS, 6, 6)),
        )
        for edge in (calibration, survey)
    ]
    values = [run(*(Pose(0, q[k], t[k]) for q, t in draws)) for k in range(DRAWS)]
    errors = left_residuals(
        rigid(np.array([v.rotation for v in values]), np.array([v.translation for v in values])),
        rigid(result.rotation, result.translation),
    )
    spread = np.cov(errors.T)
    static = result.static_covariance
    np.testing.assert_allclose(np.diag(spread), np.diag(static), rtol=0.12)
    assert np.all(np.diag(result.covariance) > np.diag(static))


def test_a_pose_without_static_edges_has_no_static_part():
    rng = rng_for("static-part-none")
    a, b = _pose(rng, 0, TRACKER), _pose(rng, 0, TRACKER)
    assert compose_poses(a, b).static_covariance is None
    assert invert_pose(a).static_covariance is None
    assert interpolate_pose(a, b.restamped(10), 5).static_covariance is None
    assert with_static_error(_exact(a)) == _exact(a)  # a plain pose: nothing to mark


@pytest.mark.parametrize("level", ["full", "worker"])
def test_the_static_part_travels_on_the_wire(level: str):
    rng = rng_for("static-part-wire")
    marked = with_static_error(_pose(rng, 5, CALIBRATION))
    value = compose_poses(marked, _pose(rng, 5, TRACKER))
    decoded = decode(encode(value), ErrorPose, level if level == "full" else WORKER)
    assert decoded == value
    assert decode(encode(_pose(rng, 5, TRACKER))).static_covariance is None


def _fused_covariance(static: bool) -> np.ndarray:
    """The fusion's covariance after 3 s of a calibrated tracker's path at 60 Hz (a body at
    rest, the process noise small), its samples' calibration share marked static or not, as
    ``Fusion.push`` takes them."""
    rng = rng_for("static-part-fusion")
    fusion = lookup("fusion")({"angular_noise": 1e-6, "linear_noise": 1e-6})
    q, t = random_quaternion(rng), np.array([0.2, 0.1, 1.5])
    outputs = []
    for k in range(180):
        covariance = CALIBRATION + TRACKER
        (qs,), (ts,) = perturb_with_covariances(rng, q[None], t[None], TRACKER[None])
        sample = ErrorPose(1_000_000_000 + k * 16 * MS, qs, ts, covariance)
        if static:
            sample = ErrorPose(sample.timestamp_ns, qs, ts, covariance, CALIBRATION)
        outputs += fusion.push("AB", sample, "relation/art").outputs.values()
    return outputs[-1].covariance


def test_the_fusion_does_not_average_a_static_error_away():
    """Told the static part, the fused covariance keeps the calibration's error (a fixed
    offset no number of samples averages out): at least 90 % of its variance on every axis;
    not told, the filter claims less than a quarter of it after 180 samples."""
    considered, white = _fused_covariance(static=True), _fused_covariance(static=False)
    assert np.all(np.diag(considered) > 0.9 * np.diag(CALIBRATION))
    assert np.all(np.diag(white) < 0.25 * np.diag(CALIBRATION))


def test_a_fixed_error_binding_round_trips_and_must_be_static():
    binding = InputBinding("AB", "ubitrack/test/data/db/C_HT", static=True, fixed_error=True)
    assert (
        parse_bindings([binding.as_dict(), {"port": "BC", "key": "k", "trigger": True}])[0]
        == binding
    )
    for raw in (
        {"port": "AB", "key": "k", "trigger": True, "fixed_error": True},
        {"port": "AB", "key": "k", "trigger": True, "static": True, "fixed_error": "yes"},
    ):
        with pytest.raises(SpecError, match="fixed_error"):
            parse_bindings([raw])
