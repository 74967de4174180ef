"""Data liveness, live: a provider that keeps its token but stops publishing an edge reports it
quiet (``io/provider.py``) and the agent plans without it (``agent/liveness.py``) while another
provider offers an alternative, and gets it back when its data returns. The situation of issue
11: ``ubitrack sim art`` dead, its DTrack adapter alive and still announcing the A.R.T. edges."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from tests.integration.test_agent import WT_HT, assert_true_pose, fresh_samples, setup  # noqa: F401
from tests.integration.zenoh_helpers import wait_until
from ubitrack_agent.core import ErrorPose, se3
from ubitrack_agent.io.application import Relation
from ubitrack_agent.io.provider import STALE_MIN_S, EdgeAnnouncement, Provider
from ubitrack_agent.sim_trackers.exact_tracker import tracker_pose, true_wt_ht

pytestmark = pytest.mark.integration

RATE_HZ = 100.0
REWIRE_S = STALE_MIN_S + 4.0
"""The documented stale window at 100 Hz (1 s), plus replanning and starting the new flow."""


class PausableTracker:
    """An exact tracker (as ``ubitrack_agent.sim_trackers.exact_tracker``) in this process, through
    the ``Provider`` API: ``T->WT`` static and ``T->HT`` at 100 Hz; :meth:`pause` stops publishing
    ``T->HT`` while the provider and its token stay."""

    def __init__(self, session, keys, provider: str, tracker: str, yaw: float, x: float) -> None:
        self.paused = threading.Event()
        self._stop = threading.Event()
        self._pose = tracker_pose(yaw, x)
        edges = [
            EdgeAnnouncement(tracker, "HT", "6D", name="HT", rate=RATE_HZ, sigma=1e-3),
            EdgeAnnouncement(tracker, "WT", "6D", static=True, name="WT", sigma=1e-3),
        ]
        self.provider = Provider(session, keys, provider, edges)
        self._cov = np.diag([1e-6] * 6)
        self.provider.publish("WT", ErrorPose(time.time_ns(), *self._pose, self._cov))
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(1.0 / RATE_HZ):
            if not self.paused.is_set():
                now = time.time_ns()
                q, t = se3.compose(*self._pose, *true_wt_ht(now))
                self.provider.publish("HT", ErrorPose(now, q, t, self._cov))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        self.provider.close()


def reads(status: dict, edge_id: str) -> bool:
    """Whether a component of the agent's plan reads the measured edge ``edge_id``."""
    return any(
        binding["key"].endswith(f"/data/{edge_id}")
        for component in status["components"].values()
        for binding in component["inputs"]
    )


def test_an_edge_whose_data_stopped_is_planned_without_until_it_returns(setup):  # noqa: F811
    setup.start_agent()
    trackers = [
        PausableTracker(setup.session, setup.keys, "art", "ART", 30.0, 2.0),
        PausableTracker(setup.session, setup.keys, "ir", "IR", 100.0, -1.0),
    ]
    relation = Relation(setup.session, setup.keys, WT_HT, application="app")
    try:
        wait_until(lambda: "fusion" in setup.alive_services().values(), timeout=30)
        art = trackers[0]

        art.paused.set()  # the provider lives, its data stops
        paused = time.monotonic()
        status = wait_until(
            lambda: (
                (s := setup.status())
                and "art/HT" in s["stale_edges"]
                and not reads(s, "art/HT")
                and s
            ),
            timeout=REWIRE_S,
        )
        assert "art" in status["providers"]  # still announced
        wait_until(lambda: "fusion" not in setup.alive_services().values(), timeout=REWIRE_S)
        print(f"rewired without art/HT after {time.monotonic() - paused:.2f} s")
        for sample in fresh_samples(relation, 20):  # the other tracker serves the relation
            assert_true_pose(sample)

        art.paused.clear()  # data again: fusion returns
        wait_until(lambda: "fusion" in setup.alive_services().values(), timeout=REWIRE_S + 10)
        status = setup.status()
        assert status["stale_edges"] == []
        assert status["counters"]["stale_edges"] == 1
        assert status["counters"]["returned_edges"] == 1
        for sample in fresh_samples(relation, 20):
            assert_true_pose(sample)
    finally:
        relation.close()
        for tracker in trackers:
            tracker.close()
