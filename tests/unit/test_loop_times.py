"""The agent loop's pass and handler times (``agent/loop_times.py``), as the status shows
them."""

from __future__ import annotations

import time

import pytest

from ubitrack_agent.agent.loop_times import LoopTimes


def test_a_window_names_its_longest_pass_and_slowest_handler_then_starts_afresh():
    times = LoopTimes()
    with times.handler("status"):
        time.sleep(0.02)
    with times.handler("reconcile"):
        pass
    with times.handler("status"):  # a shorter run: the longest is kept
        pass
    times.pass_done(0.03)
    times.pass_done(0.01)
    window = times.window()
    assert window is times.last
    assert window["passes"] == 2 and window["slowest_pass_s"] == 0.03
    assert window["slowest_handler"] == "status" and window["slowest_handler_s"] >= 0.02
    assert window["window_s"] >= window["slowest_handler_s"]
    empty = times.window()
    assert empty["passes"] == 0 and empty["slowest_handler"] is None
    assert empty["slowest_pass_s"] == empty["slowest_handler_s"] == 0.0


def test_a_handler_that_raises_is_timed_too():
    times = LoopTimes()
    with pytest.raises(RuntimeError), times.handler("fragments"):
        raise RuntimeError("boom")
    assert times.window()["slowest_handler"] == "fragments"
