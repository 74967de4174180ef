"""Construction-time validation of every measurement type."""

import math

import numpy as np
import pytest

from ubitrack_agent.core import (
    MEASUREMENT_TYPES,
    CameraIntrinsics,
    ErrorPose,
    MeasurementError,
    Pose,
    Position2D,
    Position3D,
    PositionList2D,
    PositionList3D,
    Projection,
    Rotation3D,
)
from ubitrack_agent.core.measurements import normalise_typed_quaternion

Q = [0.0, 0.0, 0.0, 1.0]
K = [[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]]


def test_registry_has_every_type_once():
    assert set(MEASUREMENT_TYPES) == {
        "Pose",
        "ErrorPose",
        "Position3D",
        "Position2D",
        "Rotation3D",
        "PositionList3D",
        "PositionList2D",
        "Projection",
        "CameraIntrinsics",
    }
    srg = {cls.SRG_TYPE for cls in MEASUREMENT_TYPES.values()}
    assert srg == {"6D", "3D", "2D", "3R", "3x4", "intrinsics"}


def test_values_are_read_only_float64():
    pose = Pose(1, Q, [1, 2, 3])
    assert pose.translation.dtype == np.float64
    with pytest.raises(ValueError):
        pose.translation[0] = 5.0


@pytest.mark.parametrize(
    "make, field, message",
    [
        (lambda: Pose(-1, Q, [0, 0, 0]), "Pose.timestamp_ns", "out of range"),
        (lambda: Pose(2**63, Q, [0, 0, 0]), "Pose.timestamp_ns", "out of range"),
        (lambda: Pose(1.5, Q, [0, 0, 0]), "Pose.timestamp_ns", "integer"),
        (lambda: Pose(True, Q, [0, 0, 0]), "Pose.timestamp_ns", "integer"),
        (lambda: Pose(1, [0, 0, 0, 2], [0, 0, 0]), "Pose.rotation", "unit quaternion"),
        (lambda: Pose(1, [0, 0, 1], [0, 0, 0]), "Pose.rotation", "shape must be 4"),
        (lambda: Pose(1, Q, [0, math.nan, 0]), "Pose.translation", "NaN"),
        (lambda: Pose(1, Q, [0, math.inf, 0]), "Pose.translation", "NaN or infinity"),
        (lambda: Pose(1, Q, "abc"), "Pose.translation", "not an array of numbers"),
        (lambda: Pose(1, Q, None), "Pose.translation", "required"),
        (
            lambda: ErrorPose(1, Q, [0, 0, 0], np.eye(6) - 2 * np.eye(6)),
            "ErrorPose.covariance",
            "positive semi-definite",
        ),
        (
            lambda: ErrorPose(1, Q, [0, 0, 0], np.triu(np.ones((6, 6)))),
            "ErrorPose.covariance",
            "symmetric",
        ),
        (lambda: Position3D(1, [1, 2]), "Position3D.position", "shape must be 3"),
        (lambda: Position2D(1, [1, 2], np.eye(3)), "Position2D.covariance", "shape must be 2x2"),
        (lambda: Rotation3D(1, [1, 1, 0, 0]), "Rotation3D.rotation", "unit quaternion"),
        (lambda: PositionList3D(1, np.zeros((4, 2))), "PositionList3D.positions", "Nx3"),
        (lambda: PositionList2D(1, np.zeros(4)), "PositionList2D.positions", "Nx2"),
        (lambda: Projection(1, np.zeros((3, 4))), "Projection.matrix", "singular"),
        (
            lambda: CameraIntrinsics(1, [[800, 0, 320], [1, 800, 240], [0, 0, 1]]),
            "CameraIntrinsics.matrix",
            "form",
        ),
        (
            lambda: CameraIntrinsics(1, [[-8, 0, 320], [0, 800, 240], [0, 0, 1]]),
            "CameraIntrinsics.matrix",
            "positive",
        ),
        (lambda: CameraIntrinsics(1, K, np.zeros(3)), "CameraIntrinsics.distortion", "one of"),
        (lambda: CameraIntrinsics(1, K, image_size=(640,)), "CameraIntrinsics.image_size", "pair"),
        (
            lambda: CameraIntrinsics(1, K, image_size=(640, 0)),
            "CameraIntrinsics.image_size",
            "[1, 2**20]",
        ),
    ],
)
def test_invalid_values_name_the_field(make, field, message):
    with pytest.raises(MeasurementError) as info:
        make()
    assert str(info.value).startswith(field + ":")
    assert message in str(info.value)


def test_valid_values_of_every_type():
    cov3 = np.diag([1e-6, 2e-6, 3e-6])
    values = [
        Pose(0, Q, [0, 0, 0]),
        ErrorPose(1, Q, [1, 2, 3], np.zeros((6, 6))),
        Position3D(2, [1, 2, 3], cov3),
        Position3D(2, [1, 2, 3]),
        Position2D(3, [10.5, 20.25], np.eye(2)),
        Rotation3D(4, [0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)]),
        PositionList3D(5, np.zeros((0, 3))),
        PositionList2D(6, np.ones((7, 2))),
        Projection(7, np.hstack((np.array(K), np.ones((3, 1))))),
        CameraIntrinsics(8, K, np.zeros(5), image_size=(640, 480)),
    ]
    for value in values:
        assert value == value
    assert Pose(0, Q, [0, 0, 0]) != Pose(1, Q, [0, 0, 0])
    assert Position3D(2, [1, 2, 3], cov3) != Position3D(2, [1, 2, 3])


def test_quaternion_tolerance_and_no_renormalisation():
    almost = np.array([0.0, 0.0, 0.0, 1.0 + 5e-7])
    assert Pose(0, almost, [0, 0, 0]).rotation[3] == almost[3]
    with pytest.raises(MeasurementError):
        Pose(0, [0.0, 0.0, 0.0, 1.0 + 2e-6], [0, 0, 0])


TYPED = [0.7071, 0.0, 0.0, 0.7071]  # 90 degrees about x, four decimals: norm 0.99999040


def test_a_typed_quaternion_is_normalised_for_files_only():
    q = normalise_typed_quaternion("rotation", TYPED)
    assert math.isclose(float(np.linalg.norm(q)), 1.0, abs_tol=1e-15)
    assert np.allclose(q, np.array(TYPED) / np.linalg.norm(TYPED))
    assert Pose(0, q, [0, 0, 0]).rotation.tolist() == q.tolist()
    unit = [0.0, 0.6, 0.0, 0.8000001]  # a unit quaternion for the wire: kept as given
    assert normalise_typed_quaternion("rotation", unit).tolist() == unit
    with pytest.raises(MeasurementError, match=r"norm 0\.99999"):
        Pose(0, TYPED, [0, 0, 0])  # measurements (and the wire codec) stay strict


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ([0.0, 0.0, 0.0, 1.002], r"not a unit quaternion \(norm 1\.002, more than 0\.001"),
        ([0, 0, 0, 2], r"from 1\): normalise it"),
        ([0, 0, 1], "rotation: shape must be 4"),
        ([0, 0, math.nan, 1], "rotation: contains NaN"),
    ],
)
def test_a_typed_quaternion_far_from_unit_is_refused_with_a_hint(value, message):
    with pytest.raises(MeasurementError, match=message):
        normalise_typed_quaternion("rotation", value)
