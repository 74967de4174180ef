"""The periodic one-line status of long-running commands (``net.status_line``) and the lines of
the agent and the host manager."""

from __future__ import annotations

import time

from ubitrack_agent.commands.agent import status_line as agent_line
from ubitrack_agent.net.status_line import Rate, periodic_status
from ubitrack_agent.services.host import status_line as host_line


def test_lines_come_periodically_and_once_at_the_end_and_never_raise():
    shown: list[str] = []
    calls = iter(range(1000))

    def render() -> str:
        if next(calls) == 1:
            raise RuntimeError("counters torn")
        return "ok"

    with periodic_status(render, every_s=0.01, show=shown.append):
        while len(shown) < 3:
            time.sleep(0.005)
    assert shown[1] == "status unavailable: RuntimeError: counters torn"
    assert shown[0] == shown[2] == shown[-1] == "ok"
    quiet: list[str] = []
    with periodic_status(render, enabled=False, every_s=0.01, show=quiet.append):
        time.sleep(0.05)
    assert quiet == []


def test_a_rate_is_per_second_between_calls():
    count = [0]
    rate = Rate(lambda: count[0])
    time.sleep(0.05)
    count[0] = 10
    assert 0 < rate.per_second() <= 10 / 0.05  # ten events in at least 50 ms
    assert rate.per_second() == 0.0  # nothing since


def test_the_agent_and_host_lines_summarise_their_status():
    status = {
        "agent": {"id": "18ea.1", "role": "active"},
        "queries": {"C->A:6D": ["app"], "X->A:6D": ["app"]},
        "unsolved": {"X->A:6D": "no provider announces frame(s) X"},
        "components": {"a": {"alive": True}, "b": {"alive": False}},
        "providers": {"art": ["art/HT"]},
        "stale_edges": [],
        "counters": {"reconfigurations": 2},
        "problems": {"rejected_query_keys": "ignored ..."},
    }
    assert agent_line(status) == (
        "agent 18ea.1 active: 2 queries, 1 unsolved; 1 of 2 workers alive; 1 providers, "
        "0 stale edges; 2 reconfigurations, 0 restarts; problems: rejected_query_keys "
        "(ubitrack status)"
    )
    assert agent_line({}) == "agent: starting"
    host = {
        "name": "vm",
        "instances": {"a": {}},
        "pool_ready": 7,
        "pool_size": 8,
        "counters": {"requests": 3},
        "clock": None,
    }
    assert host_line(host) == (
        "host vm: 1 workers running, pool 7 of 8 ready; 3 requests, 0 workers ended on their "
        "own; no clock offset to the agent yet"
    )
    host["clock"] = {"offset_ns": -300_012_345, "uncertainty_ns": 61_000}
    assert host_line(host).endswith("; clock -300.012 ms to the agent's (+-0.061)")
