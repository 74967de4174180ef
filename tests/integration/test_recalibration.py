"""Recalibration on request, live: the store holds a wrong ``ART->T2`` (the target was
remounted, say); ``ubitrack calibrate ART T2 --recalibrate --save`` calibrates it again from
the dynamic measurements alone, the store keeps the old value in the entry's history, and the
plain static relation serves the new one, also to an application that followed it all along
(the setup: ``tests/integration/calibration_helpers.py``).
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from tests.integration.calibration_helpers import LiveCalibration, pose_error, true_art_t2
from tests.integration.zenoh_helpers import wait_until
from ubitrack_agent.core import to_json
from ubitrack_agent.io.application import Relation
from ubitrack_agent.net.keys import KeySpace, RelationId

pytestmark = pytest.mark.integration

OFFSET = np.array([0.02, 0.0, 0.0])
"""How far the stored value is off: 2 cm."""


def write_wrong_calibration(path) -> list[float]:
    """A store file whose ART->T2 is the truth moved by :data:`OFFSET`; its translation."""
    q_true, t_true = true_art_t2()
    wrong = (t_true + OFFSET).tolist()
    entry = {"from": "ART", "to": "T2", "type": "6D", "rotation": q_true.tolist()}
    edges = [{**entry, "translation": wrong}]
    path.write_text(yaml.safe_dump({"provider": "store", "edges": edges}))
    return wrong


def test_recalibrate_replaces_a_wrong_stored_value(processes, tmp_path):
    live = LiveCalibration(processes)
    calibration_file = tmp_path / "calibration.yaml"
    wrong = write_wrong_calibration(calibration_file)
    live.agent()
    live.store(calibration_file)
    static = RelationId("ART", "T2", "6D", static=True)
    with (
        live.session() as session,
        Relation(session, KeySpace(live.hub.key_prefix), static, application="user") as user,
    ):
        live.wait_for_provider(session, "store.ART_T2")
        # Without the trackers only the stored edge joins ART and T2: nothing to recalibrate.
        out = live.run_calibrate("ART", "T2", "--recalibrate", "--timeout", "3")
        assert out.returncode == 1
        assert "without the measured static edge(s) store.ART_T2/ART_T2: " in out.stderr
        assert "no provider announces frame(s) ART, T2" in out.stderr

        live.hidden_trackers()
        wait_until(lambda: user.latest() is not None, timeout=20)
        np.testing.assert_allclose(to_json(user.latest())["translation"], wrong)

        lines = live.calibrate("--recalibrate", "--save")
        events = [line["event"] for line in lines]
        assert events[-2:] == ["converged", "saved"], events
        assert "progress" in events
        recalibrated = lines[-2]["value"]
        error_mm, error_deg = pose_error(recalibrated, true_art_t2())
        assert error_mm < 2.0 and error_deg < 0.2, (error_mm, error_deg)

        (entry,) = yaml.safe_load(calibration_file.read_text())["edges"]
        np.testing.assert_allclose(entry["translation"], recalibrated["translation"])
        assert entry["provenance"]["samples"] >= 50
        np.testing.assert_allclose(entry["history"][0]["translation"], wrong)

        def serves_new_value() -> bool:
            value = to_json(user.latest())["translation"]
            return np.allclose(value, recalibrated["translation"])

        wait_until(serves_new_value, timeout=10)  # the application following the stored edge
    (known,) = live.calibrate()  # and a new static query
    assert known["event"] == "known"
    np.testing.assert_allclose(known["value"]["translation"], recalibrated["translation"])
