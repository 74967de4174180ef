"""Hostile network input to the agent's pure parts: keys, fragments, planning, the guard.

Regression tests of the fuzz run of issue 11: each input here once raised something other
than a rejection (``ValueError`` from a key, ``OverflowError``, ``RecursionError``, ``ValueError:
min() arg is an empty sequence``) or let a NaN path win the plan.
"""

from __future__ import annotations

import dataclasses
import json
import math
import threading

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ubitrack_agent.agent import problems as problems_module
from ubitrack_agent.agent.announcements import (
    MAX_EDGES,
    AnnouncementError,
    build_srg,
    fragment_entries,
)
from ubitrack_agent.agent.flows import plan_relations, stable_choice
from ubitrack_agent.agent.loop_times import LoopTimes
from ubitrack_agent.agent.problems import Guard, Problems
from ubitrack_agent.agent.runtime import Agent
from ubitrack_agent.graph.planner import Query, plan
from ubitrack_agent.graph.srg import QUALITY_BOUNDS, SetupError, parse_setup
from ubitrack_agent.graph.templates import load_templates
from ubitrack_agent.net.keys import TOKEN_KINDS, KeyRejection, KeySpace, RelationId, Token

KEYS = KeySpace("ubitrack/test")
TEMPLATES = load_templates()
HOSTILE_NAMES = ["*", "**", "a b", "a$*b", "Ä", "", "a/b", "x" * 2000, "@admin", "a#b", "a?b"]
PREFIXES = {
    "provider": "provider/",
    "worker": "worker/",
    "pool": "pool/",
    "host": "host/",
    "agent": "agents/",
    "query": "query/C/HT/6D/dynamic/hmd/",
}


def key_of(kind: str, name: str) -> str:
    if kind == "host_exited":
        return f"{KEYS.root}/host/{name}/exited"
    if kind in ("worker", "container"):
        return f"{KEYS.root}/{kind}/{name}/1.a"
    if kind == "active_agent":
        return f"{KEYS.root}/agents/{name}/active"
    return f"{KEYS.root}/{PREFIXES[kind]}{name}"


@pytest.mark.parametrize("kind", TOKEN_KINDS)
@pytest.mark.parametrize("name", HOSTILE_NAMES)
def test_every_token_kind_rejects_hostile_names(kind, name):
    # A query key may end in a chunk of labels: there, "a/b" is one chunk too many.
    key = f"{KEYS.root}/query/C/HT/6D/dynamic/hmd/app/{name}" if kind == "query" else None
    rejected = KEYS.parse_token(kind, key or key_of(kind, name))
    assert isinstance(rejected, KeyRejection)
    assert rejected.counter == f"rejected_{kind}_keys"
    assert len(rejected.key) <= 1024


@pytest.mark.parametrize("kind", TOKEN_KINDS)
def test_every_token_kind_reads_a_good_name(kind):
    token = KEYS.parse_token(kind, key_of(kind, "good-1"))
    relation = RelationId("C", "HT", "6D") if kind == "query" else None
    incarnation = "1.a" if kind in ("worker", "container") else ""
    host = "hmd" if kind == "query" else ""
    assert token == Token(kind, "good-1", relation, incarnation, host)


@pytest.mark.parametrize("tail", ["concat-1", "concat-1/1.a/x", "concat-1/*", "concat-1/"])
def test_a_worker_key_names_an_instance_and_one_incarnation(tail):
    assert isinstance(KEYS.parse_token("worker", f"{KEYS.root}/worker/{tail}"), KeyRejection)


@settings(max_examples=300, deadline=None)
@given(kind=st.sampled_from(TOKEN_KINDS), tail=st.text(max_size=300))
def test_parse_token_is_total(kind, tail):
    assert isinstance(KEYS.parse_token(kind, key_of(kind, tail)), Token | KeyRejection)


def fragment(*edges, provider="art") -> bytes:
    return json.dumps({"provider": provider, "edges": list(edges)}).encode()


def edge(**extra):
    return {"name": "HT", "from": "ART", "to": "HT", "type": "6D", **extra}


HUGE_INT = b"1" + b"0" * 400


@pytest.mark.parametrize(
    "payload, reason",
    [
        (fragment(edge(sigma=1e200)), "field 'sigma': must be a finite number in [0, 1000]"),
        (fragment(edge(latency=1e200)), "field 'latency'"),
        (fragment(edge(sigma=10**400)), "an integer of"),
        (fragment(edge(rate=math.inf)), "field 'rate'"),
        (fragment(edge(sigma=math.nan)), "got nan"),
        (fragment(edge(sigma=-math.inf)), "field 'sigma'"),
        (fragment(edge(rate=10**5 + 1)), "field 'rate'"),
        (fragment(edge(latency=61)), "field 'latency'"),
        (b'{"provider": "art", "edges": [' + b"[" * 50_000 + b"]" * 50_000 + b"]}", "nested"),
        (b'{"provider": "art", "edges": [{"sigma": ' + b"9" * 5000 + b"}]}", "not JSON"),
        (fragment(edge(sigma=[[[[1]]]])), "expected int or float"),
        (fragment(edge(name="n" * 100_000)), "longer than"),
        (fragment(edge(to="HT" * 100)), "longer than 128"),
        (fragment(*(edge(name=f"e{i}") for i in range(MAX_EDGES + 1))), "1 to 1000"),
        (fragment(edge(), provider=10**400), "names provider an integer"),
    ],
)
def test_hostile_fragments_are_rejected_with_a_reason(payload, reason):
    with pytest.raises(AnnouncementError) as info:
        fragment_entries("art", payload)
    assert reason in str(info.value)


JSON_VALUES = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(min_value=-(10**30), max_value=10**30)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=5), inner),
    max_leaves=8,
)


@settings(max_examples=300, deadline=None)
@given(
    number=st.sampled_from(sorted(QUALITY_BOUNDS)),
    value=JSON_VALUES,
    field=st.sampled_from(["name", "from", "to", "type", "static", "mode"]),
    other=JSON_VALUES,
)
def test_fragment_entries_only_ever_rejects(number, value, field, other):
    for payload in (fragment(edge(**{number: value})), fragment(edge(**{field: other}))):
        try:
            entries = fragment_entries("art", payload)
        except AnnouncementError:
            continue
        srg = build_srg({"art": entries})  # what passes plans with finite arithmetic
        for _, _, quality in srg.edges(data="quality"):
            assert all(math.isfinite(x) for x in vars(quality).values())


def test_setup_files_share_the_bounds():
    with pytest.raises(SetupError, match="field 'sigma'"):
        parse_setup({"edges": [{"from": "A", "to": "B", "type": "6D", "sigma": float("nan")}]})


def two_trackers(sigma_a: float, sigma_b: float):
    entries = [
        {"from": "W", "to": "H", "type": "6D", "provider": "a", "id": "a/H", "sigma": sigma_a},
        {"from": "W", "to": "H", "type": "6D", "provider": "b", "id": "b/H", "sigma": sigma_b},
    ]
    return build_srg({"live": entries})


def test_exact_edges_plan_with_finite_costs():
    solutions = plan(two_trackers(0.0, 0.0), TEMPLATES, Query("W", "H", "6D"))
    assert all(math.isfinite(s.cost) for s in solutions)


def test_the_stable_choice_takes_a_solution_even_when_costs_are_not_numbers():
    solutions = plan(two_trackers(0.001, 0.002), TEMPLATES, Query("W", "H", "6D"))
    best = solutions[0]
    nan_first = [dataclasses.replace(best, edge=dataclasses.replace(best.edge, cost=math.nan))]
    nan_first += solutions[1:]
    running = {"some-running-component"}
    choose = stable_choice(running, {"W->H:6D": running})
    assert choose(Query("W", "H", "6D"), nan_first) is nan_first[0]


def test_planning_every_relation_survives_a_zero_sigma():
    planned = plan_relations(two_trackers(0.0, 0.001), TEMPLATES, [RelationId("W", "H", "6D")])
    assert not planned.unsolved


def test_a_failing_handler_is_counted_and_returns_its_default():
    problems = Problems()
    guard = Guard(problems)

    def broken(value):
        raise RecursionError(f"bad {value}")

    assert guard.call("liveliness", broken, 1, default=False) is False
    assert guard.call("liveliness", broken, 2, default=False) is False
    assert problems.counters["failed_liveliness"] == 2
    assert "RecursionError: bad 2" in problems.last["failed_liveliness"]


def test_a_periodic_handler_that_keeps_failing_backs_off(monkeypatch):
    now = [100.0]
    monkeypatch.setattr(problems_module.time, "monotonic", lambda: now[0])
    problems = Problems()
    guard = Guard(problems)
    calls = []

    def broken():
        calls.append(now[0])
        raise ValueError("the same state again")

    for _ in range(100):  # 100 passes of the loop within 0.3 s: one call
        guard.periodic("replan", broken, None)
        now[0] += 0.003
    assert len(calls) == 1
    now[0] += problems_module.BACKOFF_S
    guard.periodic("replan", broken, None)
    now[0] += problems_module.BACKOFF_S  # the pause doubled: still skipped
    guard.periodic("replan", broken, None)
    assert len(calls) == 2
    assert problems.counters["failed_replan"] == 2


def test_rejections_are_logged_rate_limited(caplog):
    problems = Problems()
    for index in range(2000):
        problems.report("rejected_worker_keys", "ignored %r", index)
    assert problems.counters["rejected_worker_keys"] == 2000
    assert problems.last["rejected_worker_keys"] == "ignored 1999"
    assert len(caplog.records) == 12  # the first ten, the 1000th and the 2000th


def test_the_live_srg_leaves_out_stale_edges():
    entries = [
        {"from": "W", "to": "H", "type": "6D", "provider": "a", "id": "a/H", "rate": 60},
        {"from": "W", "to": "H", "type": "6D", "provider": "b", "id": "b/H", "rate": 60},
    ]
    srg = build_srg({"live": entries}, without={"a/H"})
    assert [key for _, _, key in srg.edges(keys=True)] == ["b/H"]


def test_a_failing_loop_leaves_the_workers_running_and_a_clean_stop_ends_them():
    agent = Agent.__new__(Agent)  # the loop alone: no session
    agent._stop = threading.Event()
    agent._guard = Guard(Problems())
    agent.loop_times = LoopTimes()
    closed = []
    agent._close = lambda stop_workers: closed.append(stop_workers)

    def broken():
        raise RuntimeError("the loop itself")

    agent._next_batch = broken
    with pytest.raises(RuntimeError):
        agent.run()
    agent._stop.set()
    agent.run()
    assert closed == [False, True]
