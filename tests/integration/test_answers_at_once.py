"""The agent's answer at once (issue 31, item 1), live: ``ubitrack subscribe``, ``ubitrack
calibrate`` and ``Relation`` end with the reason as soon as the agent says it cannot serve a
relation (with a "did you mean" for frames named almost like announced ones), say "no agent"
when none is there, print a flow's progress while it starts, and with ``--wait`` /
``keep_waiting`` wait on instead.

An exit that the answer caused, not the time-out, is told by its message: a time-out's says
"within <timeout> s", an answer's does not. No timing is asserted (``bench/answer_latency_bench.py``
measures it).
"""

from __future__ import annotations

import json
import re
import subprocess
import sys

import pytest

from tests.integration.calibration_helpers import LiveCalibration
from tests.integration.test_agent import WT_HT, Setup, opened
from tests.integration.zenoh_helpers import free_port, member_flags, wait_until
from ubitrack_agent.io.application import Relation, UnsolvedRelation
from ubitrack_agent.net.keys import RelationId

pytestmark = pytest.mark.integration


CLI = [sys.executable, "-m", "ubitrack_agent.cli"]


def ubitrack(*command: str, timeout: float = 90) -> subprocess.CompletedProcess:
    return subprocess.run(
        [*CLI, *command],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


@pytest.fixture
def setup(processes):
    yield from opened(processes)


@pytest.fixture
def tracked(setup: Setup) -> Setup:
    """The agent and a tracker (frames ART, WT, HT), announced."""
    setup.start_agent()
    setup.tracker("art", "ART", 30.0, 2.0)
    wait_until(lambda: "art" in (setup.status() or {}).get("providers", {}), timeout=30)
    return setup


def test_an_unservable_relation_ends_at_once_with_the_reason(tracked: Setup):
    flags = member_flags(tracked.port, tracked.domain)
    out = ubitrack("subscribe", "WT", "NOPE", *flags)  # its time-out: the default 10 s
    assert out.returncode == 1, out.stderr
    reason = "WT->NOPE:6D: the agent cannot serve it: no provider announces frame(s) NOPE"
    assert f"ubitrack subscribe: {reason}" in out.stderr, out.stderr
    assert "within" not in out.stderr and "did you mean" not in out.stderr

    out = ubitrack("calibrate", "WT", "NOPE", *flags)  # its time-out: the default 300 s
    assert out.returncode == 1, out.stderr
    assert "ubitrack calibrate: WT->NOPE:6D static: the agent cannot serve it: " in out.stderr
    assert "did not converge within" not in out.stderr


def test_frames_named_almost_like_announced_ones_get_a_did_you_mean(tracked: Setup):
    flags = member_flags(tracked.port, tracked.domain)
    out = ubitrack("subscribe", "wt", "ht", *flags)
    assert out.returncode == 1, out.stderr
    assert out.stderr.rstrip().endswith(
        "no provider announces frame(s) wt, ht; did you mean WT->HT?"
    )
    out = ubitrack("calibrate", "ART", "WTT", "--json", *flags)
    assert out.returncode == 1, out.stderr
    (line,) = [json.loads(line) for line in out.stdout.splitlines()]
    assert line["event"] == "unsolved", line
    assert line["reason"].endswith(
        "is not in the SRG and no calibration introduces it "
        "(frames considered: ART, HT, WT); did you mean ART->WT?"
    )


def test_no_agent_is_said_as_such(setup: Setup):
    """Nobody listens where the commands look: they say so within seconds, not at their
    time-outs (10 s, 300 s), naming where they looked."""
    port = free_port()
    flags = member_flags(port, f"nobody{port}")
    for command in ("subscribe", "calibrate"):
        out = ubitrack(command, "C", "A", *flags)
        assert out.returncode == 1, out.stderr
        assert f"no agent on tcp/127.0.0.1:{port}/nobody{port} within 1.5 s" in out.stderr
        assert "--wait waits for one" in out.stderr
    out = ubitrack("subscribe", "C", "A", "--wait", "--timeout", "3", *flags)
    assert out.returncode == 1, out.stderr
    assert f"no agent on tcp/127.0.0.1:{port}/nobody{port} within 3 s" in out.stderr


def test_with_wait_a_flow_whose_sensor_comes_later_is_followed_to_its_samples(setup: Setup):
    setup.start_agent()
    flags = member_flags(setup.port, setup.domain)
    out = ubitrack("subscribe", "WT", "HT", "--wait", "--timeout", "3", *flags)
    assert out.returncode == 1, out.stderr  # waited to the time-out, then said why
    assert "no sample of WT->HT:6D within 3.0 s: the agent cannot serve it" in out.stderr

    waiting = subprocess.Popen(
        [*CLI, "subscribe", "WT", "HT", "--wait", "--count", "1", "--timeout", "60", *flags],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    setup.processes.append(waiting)
    setup.tracker("art", "ART", 30.0, 2.0)  # the sensor comes after the query
    stdout, stderr = waiting.communicate(timeout=90)
    assert waiting.returncode == 0, stderr
    assert json.loads(stdout)["type"] == "ErrorPose"
    progress = [line for line in stderr.splitlines() if "planned:" in line]
    assert progress[0] == "ubitrack subscribe: WT->HT:6D: planned: 2 components, 0 alive"
    assert progress[-1] == "ubitrack subscribe: WT->HT:6D: planned: 2 components, 2 alive"


def test_the_api_raises_the_reason_at_once_unless_asked_to_keep_waiting(tracked: Setup):
    nowhere = RelationId("WT", "NOPE", "6D")
    with Relation(tracked.session, tracked.keys, nowhere, application="a") as relation:
        with pytest.raises(UnsolvedRelation) as raised:
            relation.wait_for(timeout=60.0)
        assert raised.value.timeout is None  # the answer ended it, not the timeout
        assert raised.value.reason == "no provider announces frame(s) NOPE"
    with Relation(tracked.session, tracked.keys, RelationId("wt", "HT", "6D")) as relation:
        with pytest.raises(UnsolvedRelation) as raised:
            relation.wait_for(timeout=60.0)
        assert raised.value.reason.endswith("wt; did you mean WT->HT?")  # the agent's hint
    with Relation(
        tracked.session, tracked.keys, nowhere, application="b", keep_waiting=True
    ) as relation:
        with pytest.raises(UnsolvedRelation) as raised:
            relation.wait_for(timeout=2.0)
        assert raised.value.timeout == 2.0  # kept waiting to its timeout
    with Relation(tracked.session, tracked.keys, WT_HT, application="c") as relation:
        relation.wait_for(timeout=30.0)  # a served relation's samples, as ever


def test_calibrate_shows_its_flow_starting_before_its_progress(processes):
    live = LiveCalibration(processes)
    live.agent()
    live.hidden_trackers()
    out = live.run_calibrate("ART", "T2", "--wait", "--timeout", "40")
    events = [json.loads(line) for line in out.stdout.splitlines()]
    kinds = [event["event"] for event in events]
    assert "planned" in kinds and "progress" in kinds, out.stdout + out.stderr[-2000:]
    assert kinds.index("planned") < kinds.index("progress")
    lines = [event["line"] for event in events if event["event"] == "planned"]
    counts = [tuple(map(int, re.findall(r"\d+", line))) for line in lines]
    assert all(re.fullmatch(r"planned: \d+ components, \d+ alive", line) for line in lines)
    assert counts[0][1] == 0 and counts[-1][1] == counts[-1][0], lines  # none, then all alive
