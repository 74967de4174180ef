"""Answers, not silence (issue 14, item 1): an application learns why nothing comes.

With no agent on the domain, waiting for a sample ends with ``NoAgent``; with an agent that
cannot serve the relation, with ``UnsolvedRelation`` and the planner's reason, which the agent
also publishes on the query's answer key; a served relation's answer names its workers.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.integration.test_agent import WT_HT, Setup, opened
from tests.integration.zenoh_helpers import member_flags, wait_until
from ubitrack_agent.io.application import NoAgent, Relation, UnsolvedRelation
from ubitrack_agent.net.answer import parse_answer
from ubitrack_agent.net.keys import RelationId
from ubitrack_agent.net.transport import fetch_latest

pytestmark = pytest.mark.integration

NOWHERE = RelationId("NOPE", "HT", "6D")


def flags(setup: Setup) -> list[str]:
    return member_flags(setup.port, setup.domain)


@pytest.fixture
def setup(processes):
    yield from opened(processes)


def test_without_an_agent_waiting_ends_with_no_agent(setup: Setup):
    with Relation(setup.session, setup.keys, WT_HT, application="app") as relation:
        with pytest.raises(NoAgent, match=f"no agent is active on {setup.keys.root}"):
            relation.wait_for(timeout=1.0)
        with pytest.raises(NoAgent):
            relation.get(timeout=0.2)
        assert relation.answer is None
    command = ["subscribe", "WT", "HT", "--timeout", "1", *member_flags(setup.port, setup.domain)]
    out = subprocess.run(
        [sys.executable, "-m", "ubitrack_agent.cli", *command],
        capture_output=True,
        text=True,
        timeout=60,
    )
    network = f"tcp/127.0.0.1:{setup.port}/{setup.domain}"
    assert out.returncode == 1 and f"no agent on {network} within 1 s" in out.stderr, out.stderr


def test_the_agent_answers_why_it_cannot_serve_and_what_serves(setup: Setup, tmp_path: Path):
    setup.start_agent()
    setup.tracker("art", "ART", 30.0, 2.0)
    with (
        Relation(setup.session, setup.keys, NOWHERE, application="lost") as lost,
        Relation(  # asked while the tracker starts
            setup.session, setup.keys, WT_HT, application="app", keep_waiting=True
        ) as served,
    ):
        with pytest.raises(UnsolvedRelation, match="no provider announces frame") as raised:
            lost.wait_for(timeout=3.0)
        assert "NOPE" in raised.value.reason
        assert lost.answer is not None and not lost.answer.served
        assert lost.answer.reason == raised.value.reason
        published = wait_until(  # asked again while a loaded machine's reply is late
            lambda: fetch_latest(setup.session, setup.keys.answer(NOWHERE), timeout=1.0)
        )
        assert [parse_answer(p) for p in published] == [lost.answer]  # and on its key

        served.wait_for(timeout=30.0)
        wait_until(lambda: served.answer is not None and served.answer.served, timeout=10)
        answer = served.answer
        assert answer.reason is None and answer.key == setup.keys.relation(WT_HT)
        components = (setup.status() or {})["components"]
        assert answer.components == {i: c["service"] for i, c in components.items()}
        assert sorted(answer.components.values()) == ["concatenation", "inversion"]

        # The live picture of that flow (figure 6's style): source, components, application.
        dot = tmp_path / "flow.dot"
        command = ["status", "--dot", str(dot), "--rate-window", "0.5"]
        out = subprocess.run(
            [sys.executable, "-m", "ubitrack_agent.cli", *command, *flags(setup)],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert out.returncode == 0, out.stderr
        picture = dot.read_text()
        assert '"provider art" [shape=house' in picture
        for instance in answer.components:
            assert f'"{instance}" [shape=box, color=black' in picture  # alive
        assert '-> "application WT->HT:6D"' in picture and "app\\nWT->HT:6D" in picture
        assert re.search(r'-> "application WT->HT:6D" \[label="6D, [1-9]\d* Hz"\]', picture)


def test_status_names_the_active_agent_and_says_when_none_is(setup: Setup):
    command = [sys.executable, "-m", "ubitrack_agent.cli", "status", "--timeout", "1"]
    flags = member_flags(setup.port, setup.domain)
    out = subprocess.run([*command, *flags], capture_output=True, text=True, timeout=60)
    assert out.returncode == 1 and "no active agent answers" in out.stderr, out.stderr
    setup.start_agent()
    agent_id = setup.status()["agent"]["id"]
    out = subprocess.run([*command, *flags], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith(f"agent {agent_id} (active) on {setup.keys.root}")
