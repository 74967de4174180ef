"""The registered pattern services on noise-free synthetic scenes, and time expansion."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bench.synthetic import (
    CAMERA_MATRIX,
    body_noise_covariances,
    hand_eye_scene,
    noisy_hand_eye_scene,
    perturb_with_covariances,
    pivot_scene,
    rng_for,
)
from ubitrack_agent.core import (
    ErrorPose,
    Pose,
    Position2D,
    Position3D,
    Projection,
    Rotation3D,
    quaternions,
    se3,
)
from ubitrack_agent.net.spec import parse_time_expansion
from ubitrack_agent.services.algorithms import fuse_poses, hand_eye_calibration, tip_calibration
from ubitrack_agent.services.components.averaging import motion_window
from ubitrack_agent.services.expansion import BatchProgress, TimeAccumulator
from ubitrack_agent.services.registry import lookup

T = 1_000


def make(name: str, **parameters):
    return lookup(name)(parameters)


def assert_pose(measurement, q, t, atol=1e-8):
    np.testing.assert_allclose(
        se3.to_matrix(measurement.rotation, measurement.translation), se3.to_matrix(q, t), atol=atol
    )


def scene(name: str, n: int = 8):
    rng = rng_for(name)
    q, t = Rotation.random(rng=rng).as_quat(), rng.uniform(-0.5, 0.5, 3)
    points_b = rng.uniform(-0.2, 0.2, (n, 3))
    return rng, q, t, points_b


def test_pose_estimation_3d3d_space_expanded_with_missing_rows():
    _, q, t, points_b = scene("3d3d")
    points_a = se3.transform_points(q, t, points_b)
    af = [Position3D(T, p) for p in points_a] + [None]
    bf = [Position3D(T, p) for p in points_b] + [Position3D(T, [9.0, 9.0, 9.0])]
    out = make("pose_estimation_3d3d").compute({"AF": af, "BF": bf}, T)["AB"]
    assert out.timestamp_ns == T
    assert_pose(out, q, t)
    with pytest.raises(ValueError, match="need 3"):
        make("pose_estimation_3d3d").compute({"AF": af[:2], "BF": bf[:2]}, T)


def camera_scene(name: str):
    """Camera frame C = optical frame rotated; projection C->I; object O with features."""
    _rng, q_co, _, features = scene(name, 10)
    t_co = np.array([0.05, -0.02, 1.5])
    q_opt, t_opt = Rotation.from_euler("z", 10, degrees=True).as_quat(), np.array([0.01, 0, 0])
    projection = CAMERA_MATRIX @ se3.to_matrix(q_opt, t_opt)[:3]
    in_c = se3.transform_points(q_co, t_co, features)
    homogeneous = (projection @ np.c_[in_c, np.ones(len(in_c))].T).T
    pixels = homogeneous[:, :2] / homogeneous[:, 2:]
    return projection, (q_co, t_co), features, in_c, pixels


def test_pose_estimation_2d3d_reexpresses_pnp_in_the_camera_frame():
    projection, (q_co, t_co), features, _, pixels = camera_scene("2d3d")
    values = {
        "CI": Projection(T, projection),
        "IF": [Position2D(T, x) for x in pixels],
        "OF": [Position3D(T, f) for f in features],
    }
    out = make("pose_estimation_2d3d").compute(values, T)["CO"]
    assert_pose(out, q_co, t_co, atol=1e-6)
    robust = make("pose_estimation_2d3d", ransac=True).compute(values, T)["CO"]
    assert_pose(robust, q_co, t_co, atol=1e-6)


def test_pose_estimation_2d3d_takes_the_covariance_the_camera_announces():
    projection, _, features, _, pixels = camera_scene("2d3d-announced")
    announced = np.diag([0.3, 0.5]) ** 2
    values = {
        "CI": Projection(T, projection),
        "IF": [Position2D(T, x, announced) for x in pixels],
        "OF": [Position3D(T, f) for f in features],
    }
    with_covariances = make("pose_estimation_2d3d").compute(values, T)["CO"].covariance
    given = make("pose_estimation_2d3d", pixel_sigma=0.4).compute(values, T)["CO"].covariance
    values["IF"] = [Position2D(T, x) for x in pixels]  # none announced: from the residuals
    from_residuals = make("pose_estimation_2d3d").compute(values, T)["CO"]
    # noise-free pixels: the residuals say nothing is uncertain, the camera says otherwise
    assert np.trace(from_residuals.covariance) < 1e-12 < np.trace(with_covariances)
    assert 0.5 < np.trace(with_covariances) / np.trace(given) < 1.5


def test_projective_calibration_recovers_the_projection():
    projection, _, _, in_c, pixels = camera_scene("dlt")
    values = {"IF": [Position2D(T, x) for x in pixels], "CF": [Position3D(T, p) for p in in_c]}
    out = make("projective_calibration").compute(values, T)["CI"]
    scale = projection[2, 2] / out.matrix[2, 2]
    np.testing.assert_allclose(out.matrix * scale, projection, rtol=1e-6, atol=1e-6)


def test_triangulation_from_two_views():
    rng = rng_for("triangulation")
    point = rng.uniform(-0.2, 0.2, 3)
    views = []
    for yaw in (-20.0, 25.0):
        q = Rotation.from_euler("y", yaw, degrees=True).as_quat()
        p = CAMERA_MATRIX @ se3.to_matrix(q, [0.0, 0.0, 2.0])[:3]
        x = p @ np.append(point, 1.0)
        views.append((Projection(T, p), Position2D(T, x[:2] / x[2])))
    values = {"CI": [v[0] for v in views], "IF": [v[1] for v in views]}
    out = make("triangulation").compute(values, T)["CF"]
    np.testing.assert_allclose(out.position, point, atol=1e-8)
    assert out.covariance.shape == (3, 3)


def test_hand_eye_calibration_gives_eye_in_hand_and_object_in_base():
    truth, (hand_q, hand_t, eye_q, eye_t) = hand_eye_scene(rng_for("hand-eye service"), 6)
    values = {
        "RH": [Pose(T, q, t) for q, t in zip(hand_q, hand_t, strict=True)],
        "CO": [Pose(T, q, t) for q, t in zip(eye_q, eye_t, strict=True)],
    }
    out = make("hand_eye_calibration").compute(values, T)
    assert_pose(out["HC"], truth.rotation, truth.translation, atol=1e-6)
    q_ro, t_ro = se3.compose(
        *se3.compose(hand_q[0], hand_t[0], truth.rotation, truth.translation), eye_q[0], eye_t[0]
    )
    assert_pose(out["RO"], q_ro, t_ro, atol=1e-6)
    assert isinstance(out["HC"], ErrorPose) and isinstance(out["RO"], ErrorPose)


def _hand_eye_outputs(poses, covariances, plain_eye: int | None = None):
    """The service's outputs for samples carrying ``covariances`` (ErrorPose), except the eye
    sample ``plain_eye``, which is a Pose."""
    qg, tg, qc, tc = poses
    hand_cov, eye_cov = covariances
    hands = [ErrorPose(T, *pose) for pose in zip(qg, tg, hand_cov, strict=True)]
    eyes = [ErrorPose(T, *pose) for pose in zip(qc, tc, eye_cov, strict=True)]
    if plain_eye is not None:
        eyes[plain_eye] = Pose(T, qc[plain_eye], tc[plain_eye])
    return make("hand_eye_calibration").compute({"RH": hands, "CO": eyes}, T)


def _assert_estimate(measurement, estimate):
    assert isinstance(measurement, ErrorPose)
    assert_pose(measurement, estimate.rotation, estimate.translation, atol=1e-12)
    np.testing.assert_allclose(measurement.covariance, estimate.covariance, rtol=1e-9, atol=0)


def test_hand_eye_service_is_the_refined_estimator_over_all_pairs_with_both_covariances():
    """60 rows (the old wiring switched to consecutive pairs above 50): the outputs are the
    algorithm's, weighted by the samples' covariances, and RO's covariance includes the
    uncertainty of HC (the algorithm's joint solution, not a mean of ``RH_i HC CO_i``)."""
    _, _, poses, covariances = noisy_hand_eye_scene(rng_for("hand-eye service noisy"), 60, "low")
    out = _hand_eye_outputs(poses, covariances)
    solution = hand_eye_calibration(*poses, *covariances)
    assert not solution.noise_from_residuals
    _assert_estimate(out["HC"], solution.eye_in_hand)
    _assert_estimate(out["RO"], solution.target_in_base)

    mixed = _hand_eye_outputs(poses, covariances, plain_eye=7)  # one sample without covariance
    from_residuals = hand_eye_calibration(*poses)
    assert from_residuals.noise_from_residuals
    _assert_estimate(mixed["HC"], from_residuals.eye_in_hand)
    _assert_estimate(mixed["RO"], from_residuals.target_in_base)
    assert not np.allclose(mixed["RO"].covariance, out["RO"].covariance, rtol=1e-3, atol=0)


def test_tip_calibration_weights_by_the_poses_covariances_when_every_sample_has_one():
    rng = rng_for("tip service")
    tip, pivot, (q, t) = pivot_scene(rng, 40)
    covariances = body_noise_covariances(t, np.radians(0.1), 2e-4)
    q, t = perturb_with_covariances(rng, q, t, covariances)
    poses = [ErrorPose(T, *pose) for pose in zip(q, t, covariances, strict=True)]
    service = make("tip_calibration")
    out = service.compute({"TM": poses}, T)
    solution = tip_calibration(q, t, covariances)
    for name, value, covariance in (
        ("MP", solution.tip_in_marker, solution.tip_covariance),
        ("TP", solution.pivot_in_tracker, solution.pivot_covariance),
    ):
        assert isinstance(out[name], Position3D) and out[name].timestamp_ns == T
        np.testing.assert_allclose(out[name].position, value, rtol=0, atol=1e-12)
        np.testing.assert_allclose(out[name].covariance, covariance, rtol=1e-9, atol=0)
    assert np.linalg.norm(out["MP"].position - tip) < 1e-3
    assert np.linalg.norm(out["TP"].position - pivot) < 1e-3

    poses[3] = Pose(T, q[3], t[3])  # one sample without covariance: noise from the residuals
    mixed = service.compute({"TM": poses}, T)
    from_residuals = tip_calibration(q, t)
    np.testing.assert_allclose(mixed["MP"].covariance, from_residuals.tip_covariance, rtol=1e-9)
    with pytest.raises(ValueError, match="29 poses, need 30"):
        service.compute({"TM": poses[:29]}, T)
    turns = Rotation.from_euler("z", np.arange(30.0)[:, None], degrees=True).as_quat()
    about_z = [Pose(T, turn, t[0]) for turn in turns]
    with pytest.raises(ValueError, match="one axis only"):
        service.compute({"TM": about_z}, T)


def test_fusion_of_equal_and_weighted_estimates():
    q = Rotation.random(rng=1).as_quat()
    a = ErrorPose(T, q, [1.0, 0.0, 0.0], np.eye(6) * 1e-6)
    b = ErrorPose(T, q, [1.2, 0.0, 0.0], np.eye(6) * 3e-6)
    fused = make("fusion").compute({"AB": [a, b, None]}, T)["fused"]
    np.testing.assert_allclose(fused.translation, [1.05, 0, 0], atol=1e-9)
    np.testing.assert_allclose(np.diag(fused.covariance), 0.75e-6, rtol=1e-6)
    positions = [Position3D(T, [0, 0, 0]), Position3D(T, [2, 0, 0])]
    mean = make("fusion").compute({"AB": positions}, T)["fused"]
    np.testing.assert_allclose(mean.position, [1, 0, 0])
    with pytest.raises(ValueError, match="no estimate"):
        make("fusion").compute({"AB": [None, None]}, T)


def test_fusion_of_rotations_is_the_pose_fusion_without_translation():
    rng = rng_for("fusion 3R")
    quats = Rotation.random(3, rng=rng).as_quat()
    rotations = [Rotation3D(T, q) for q in quats]
    fused = make("fusion", default_sigma=0.01).compute({"AB": [*rotations, None]}, T)["fused"]
    assert isinstance(fused, Rotation3D)
    expected = fuse_poses(quats, np.zeros((3, 3)), np.array([1e-4 * np.eye(6)] * 3))
    assert quaternions.angle(
        quaternions.multiply(fused.rotation, quaternions.conjugate(expected.rotation))
    ) == pytest.approx(0.0, abs=1e-12)
    about_z = [Rotation3D(T, Rotation.from_euler("z", d, degrees=True).as_quat()) for d in (9, 11)]
    middle = make("fusion").compute({"AB": about_z}, T)["fused"]
    assert np.degrees(quaternions.angle(middle.rotation)) == pytest.approx(10.0)
    with pytest.raises(ValueError, match="different types: Pose, Rotation3D"):
        make("fusion").compute({"AB": [rotations[0], Pose(T, quats[1], [0, 0, 0])]}, T)


def test_averaging_estimates_incrementally_and_reports_progress():
    samples = [Pose(i, [0, 0, 0, 1], [1.0 + 0.01 * (-1) ** i, 0, 0]) for i in range(60)]
    at_once = make("averaging")
    mean = at_once.compute({"AB": samples}, T)["mean"]
    assert isinstance(mean, ErrorPose)
    np.testing.assert_allclose(mean.translation, [1.0, 0, 0], atol=1e-9)
    one_by_one = make("averaging")  # as the worker feeds an incremental service
    for sample in samples:
        out = one_by_one.compute({"AB": [sample]}, sample.timestamp_ns)
    np.testing.assert_allclose(out["mean"].translation, mean.translation, atol=1e-12)
    (progress,) = one_by_one.progress().values()
    assert (progress.accepted, progress.rejected) == (60, 0)
    assert progress.status in ("averaging", "converged")
    assert progress.value["translation"] == pytest.approx(list(mean.translation))
    rotations = [
        Rotation3D(i, Rotation.from_euler("z", (9, 11)[i % 2], degrees=True).as_quat())
        for i in range(20)
    ]
    mean_rotation = make("averaging").compute({"AB": rotations}, T)["mean"]
    assert np.degrees(quaternions.angle(mean_rotation.rotation)) == pytest.approx(10.0)


def test_averaging_publishes_nothing_before_its_start_or_for_a_moving_relation():
    averaging = make("averaging")
    few = [Position3D(i, [0.0, 0.0, 1.0]) for i in range(5)]
    assert averaging.compute({"AB": few}, T) == {}
    assert averaging.progress()["mean"].status == "initialising"
    rng = np.random.default_rng(3)
    moving = make("averaging")
    for i in range(200):  # 1 mm noise, drifting 0.5 mm per sample at 30 Hz
        position = np.array([0.0005 * i, 0.0, 1.0]) + rng.normal(0, 1e-3, 3)
        stamp = i * 33_333_333
        out = moving.compute({"AB": [Position3D(stamp, position, np.eye(3) * 1e-6)]}, stamp)
    assert out == {}
    progress = moving.progress()["mean"]
    assert progress.not_static and progress.motion is not None and progress.value is None


def test_averaging_sets_the_motion_window_to_a_second_of_samples():
    def samples(period_ns, count=20):
        return [Position3D(i * period_ns, [0.0, 0.0, 1.0]) for i in range(count)]

    assert motion_window(samples(11_111_111)) == 90  # 90 Hz: the live direct computation
    assert motion_window(samples(33_333_333)) == 30
    assert motion_window(samples(100_000_000)) == 30  # never below the estimator's default
    assert motion_window(samples(1)) == 1000  # at most 1,000
    assert motion_window(samples(0)) == 30  # no time: the default


def test_pose_split():
    parts = make("pose_split").compute({"AB": ErrorPose(T, [0, 0, 0, 1], [1, 2, 3], np.eye(6))}, T)
    np.testing.assert_allclose(parts["position"].position, [1, 2, 3])
    assert isinstance(parts["rotation"], Rotation3D)


def test_time_accumulator_keeps_distinct_samples_until_the_multiplicity():
    service = make("pose_estimation_3d3d")
    accumulator = TimeAccumulator(service, parse_time_expansion({"min_motion": 0.01}))
    _, q, t, points_b = scene("tracker alignment", 5)
    kept = []
    for i, p in enumerate([points_b[0], points_b[0] + 0.001, *points_b[1:]]):
        values = {"AF": Position3D(i, se3.transform_points(q, t, p)), "BF": Position3D(i, p)}
        kept.append(accumulator.add(values))
        if accumulator.ready():
            out = service.compute(accumulator.expanded(values), i)["AB"]
    assert kept == [True, False, True, True, True, True]
    assert len(accumulator) == 5
    assert_pose(out, q, t)
    no_threshold = TimeAccumulator(make("averaging"), {})
    assert no_threshold.add({"AB": Pose(1, [0, 0, 0, 1], [0, 0, 0])})
    assert not no_threshold.add({"AB": Pose(1, [0, 0, 0, 1], [0, 0, 0])})  # the same instant
    assert no_threshold.add({"AB": Pose(2, [0, 0, 0, 1], [0, 0, 0])})


def test_time_accumulator_history_is_bounded_and_options_validated():
    accumulator = TimeAccumulator(
        make("hand_eye_calibration"), parse_time_expansion({"max_samples": 3})
    )
    for i in range(10):
        pose = Pose(i, Rotation.from_euler("z", 10 * i, degrees=True).as_quat(), [i, 0, 0])
        accumulator.add({"RH": pose, "CO": pose})
    assert len(accumulator) == 3
    incremental = TimeAccumulator(make("averaging"), {})
    for i in range(10):
        incremental.add({"AB": Pose(i, [0, 0, 0, 1], [i, 0, 0])})
    assert len(incremental) == 1 and incremental.ready()  # each new sample goes on alone
    assert [p.timestamp_ns for p in incremental.expanded({})["AB"]] == [9]
    for bad, fragment in (
        ({"min_motion": -1}, ">= 0"),
        ({"speed": 1}, "unknown options"),
        ({"max_samples": 0}, "max_samples"),
    ):
        with pytest.raises(ValueError, match=fragment):
            parse_time_expansion(bad)


def test_batch_progress_converges_on_precise_stable_results_only():
    tracker = BatchProgress(translation_tolerance=1e-3, window=3)
    precise = [Position3D(i, [0.1, 0.0, 0.0], np.eye(3) * 1e-8) for i in range(4)]
    statuses = [tracker.update(result, 10 + i, i).status for i, result in enumerate(precise)]
    assert statuses == ["averaging"] * 3 + ["converged"]  # stable over the window at last
    vague = BatchProgress(window=1)
    wide = Position3D(0, [0.1, 0.0, 0.0], np.eye(3) * 1e-4)  # 17 mm RMS
    assert [vague.update(wide, 10, 0).status for _ in range(3)] == ["averaging"] * 3
    moving = BatchProgress(window=2)
    jumps = [Position3D(i, [0.01 * i, 0.0, 0.0], np.eye(3) * 1e-8) for i in range(6)]
    assert all(moving.update(result, 10, 0).status == "averaging" for result in jumps)
    report = tracker.update(precise[0], 14, 5)
    assert report.value["position"] == [0.1, 0.0, 0.0] and report.std_translation < 1e-3


class _FilterThatWentBack:
    """A fusion filter whose newest measurement went back in time (a late measurement's replay
    gated the newest ones), so it takes an older measurement as in order."""

    def __init__(self) -> None:
        self.real = make("fusion")._filter

    def update(self, timestamp_ns, rotation, translation, covariance, **given):
        self.real.update(timestamp_ns, rotation, translation, covariance, **given)
        return "updated"

    def estimate(self, timestamp_ns):
        return self.real.estimate(timestamp_ns)


def test_asynchronous_fusion_publishes_in_time_order_only():
    fusion = make("fusion")
    fusion._filter = _FilterThatWentBack()
    pose = [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 1.0], np.eye(6) * 1e-6
    published = []
    for t in (100, 200, 150, 200, 300):
        pushed = fusion.push("AB", ErrorPose(T + t * 10**6, *pose))
        published += [value.timestamp_ns - T for value in pushed.outputs.values()]
        assert pushed.outputs or pushed.reason == "late"
    assert published == [100 * 10**6, 200 * 10**6, 300 * 10**6]
