"""The chaos suite's judgement of a delivered sample (issue 29, ``chaos_faults.judged``): the
truth at its time, its errors, and its NEES against its own covariance."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from tests.integration.chaos_faults import HT_WT, THREE_SIGMA_NEES, WT_HT, judged, true_pose
from ubitrack_agent.core import ErrorPose, quaternions

STAMP = 1_795_000_000_000_000_000
SIGMA = 1e-3


def sample(offset=(0.0, 0.0, 0.0), turn_deg: float = 0.0, covariance=None) -> ErrorPose:
    """The true WT->HT at ``STAMP``, moved by ``offset`` (m) and turned about z."""
    q, t = true_pose(WT_HT, STAMP)
    turn = Rotation.from_euler("z", turn_deg, degrees=True).as_quat()
    cov = np.diag([SIGMA**2] * 6) if covariance is None else covariance
    return ErrorPose(STAMP, quaternions.multiply(turn, q), t + np.asarray(offset), cov)


def test_a_true_sample_is_right_with_no_error():
    verdict = judged(WT_HT, sample())
    assert verdict.mm < 1e-9 and verdict.deg < 1e-6 and verdict.nees < 1e-9
    assert not verdict.wrong


def test_the_inverse_relation_is_judged_against_the_inverse_truth():
    q, t = true_pose(HT_WT, STAMP)
    assert not judged(HT_WT, ErrorPose(STAMP, q, t, np.diag([SIGMA**2] * 6))).wrong
    assert judged(HT_WT, sample()).mm > 100  # WT->HT's pose is not HT->WT's


def test_an_error_within_its_covariance_is_right_beyond_three_sigma_wrong():
    within = judged(WT_HT, sample(offset=(4e-3, 0.0, 0.0)))  # NEES 16
    beyond = judged(WT_HT, sample(offset=(5e-3, 0.0, 0.0)))  # NEES 25
    assert np.isclose(within.nees, 16.0, rtol=1e-6) and not within.wrong
    assert np.isclose(beyond.nees, 25.0, rtol=1e-6) and beyond.wrong
    assert within.nees < THREE_SIGMA_NEES < beyond.nees


def test_beyond_five_centimetres_or_five_degrees_is_wrong_whatever_the_covariance():
    loose = np.diag([1.0] * 6)  # 1 m, 57 degrees: every error is "within 3 sigma"
    assert judged(WT_HT, sample(offset=(0.0, 0.06, 0.0), covariance=loose)).wrong
    assert judged(WT_HT, sample(turn_deg=6.0, covariance=loose)).wrong
    assert not judged(WT_HT, sample(offset=(0.0, 0.04, 0.0), turn_deg=4.0, covariance=loose)).wrong


def test_a_turn_shows_in_degrees_and_in_the_nees():
    verdict = judged(WT_HT, sample(turn_deg=0.1))
    assert np.isclose(verdict.deg, 0.1, rtol=1e-6)
    assert verdict.nees > (np.radians(0.1) / SIGMA) ** 2 * 0.99  # the rotation's part at least
