"""``ubitrack ros2``: options refused before anything starts, with the reason."""

from __future__ import annotations

import pytest

from ubitrack_agent.cli import main

pytest.importorskip("rosbags", reason="the ros2 extra (rosbags) is not installed")


def test_frames_without_a_ros_name_are_all_reported_before_starting(capsys):
    assert main(["ros2", "publish", "my-frame/A", "--static", "1st/A"]) == 2
    err = capsys.readouterr().err
    assert "'my-frame' is no ROS frame id" in err and "'1st' is no ROS frame id" in err


def test_bad_options_exit_2_with_the_reason(capsys):
    assert main(["ros2", "publish"]) == 2
    assert "no relation" in capsys.readouterr().err
    assert main(["ros2", "publish", "C/A", "--ros-domain-id", "300"]) == 2
    assert "not in 0..232" in capsys.readouterr().err
    assert main(["ros2", "subscribe", "--sigma-mm", "0"]) == 2
    assert "must be positive" in capsys.readouterr().err
