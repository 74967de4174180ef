"""``ubitrack subscribe`` says why nothing comes instead of waiting in silence (issue
[surface] item 1): a bad type is refused at once, and an unservable relation ends within the
timeout with the agent's reason."""

from __future__ import annotations

import subprocess
import sys

import pytest

from tests.integration.zenoh_helpers import free_port, member_flags
from ubitrack_agent.cli import main

pytestmark = pytest.mark.integration


def test_an_unknown_type_is_refused_before_anything_starts(capsys):
    assert main(["subscribe", "C", "A", "--type", "7D"]) == 2
    assert "--type: unknown type '7D'" in capsys.readouterr().err
    assert main(["subscribe", "C", "A", "--timeout", "0"]) == 2


def test_an_unservable_relation_ends_with_the_agents_reason(processes):
    port = free_port()
    domain = f"sub{port}"
    listen = ("--listen", f"tcp/127.0.0.1:{port}", "--domain", domain)
    agent = subprocess.Popen(
        [sys.executable, "-m", "ubitrack_agent.cli", "agent", "--no-host", *listen],
        start_new_session=True,
    )
    processes.append(agent)
    # the agent may still be starting: --wait, the reason at the time-out
    command = ["subscribe", "NOPE", "A", "--wait", "--timeout", "4", *member_flags(port, domain)]
    out = subprocess.run(
        [sys.executable, "-m", "ubitrack_agent.cli", *command],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 1, out.stderr
    assert "the agent cannot serve it: no provider announces frame(s)" in out.stderr
    assert "NOPE" in out.stderr.split("cannot serve it")[1]
