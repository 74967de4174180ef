"""The simulated pivoting pointer (``ubitrack_agent.sim_trackers.pivot``): ground truth for tip
calibration."""

import numpy as np

from ubitrack_agent.core import quaternions, se3
from ubitrack_agent.services.algorithms import tip_calibration
from ubitrack_agent.sim_trackers.pivot import PivotMotion


def test_the_tip_stays_on_the_pivot_while_the_pointer_turns_about_it():
    motion = PivotMotion()
    poses = [motion.pose(t) for t in np.arange(0.0, 8.0, 1 / 60)]
    q, t = (np.array(part) for part in zip(*poses, strict=True))
    tips = se3.transform_points(q, t, np.broadcast_to(motion.tip, (len(q), 3)))
    np.testing.assert_allclose(tips, np.broadcast_to(motion.pivot, tips.shape), atol=1e-12)
    axis = quaternions.rotate(q, -np.array(motion.tip) / np.linalg.norm(motion.tip))
    # the pointer's axis (tip to marker) against the tracker's -z
    tilt = np.degrees(np.arccos(np.clip(-axis[:, 2], -1.0, 1.0)))
    assert 20.0 < tilt.max() <= motion.cone_deg + 1e-9


def test_two_seconds_of_pivoting_determine_tip_and_pivot():
    motion = PivotMotion()
    q, t = (
        np.array(part)
        for part in zip(*(motion.pose(s) for s in np.arange(0, 2, 0.05)), strict=True)
    )
    solution = tip_calibration(q, t)  # raises for a motion about one axis
    np.testing.assert_allclose(solution.tip_in_marker, motion.tip, atol=1e-9)
    np.testing.assert_allclose(solution.pivot_in_tracker, motion.pivot, atol=1e-9)
