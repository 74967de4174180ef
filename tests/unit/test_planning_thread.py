"""Planning off the agent's loop (``agent/planning.py``): the loop never waits for a plan, an
outcome made before a newer change is never applied, no change is lost, and a failed job is
asked again. The jobs here block on events the test sets, so the order is deterministic."""

from __future__ import annotations

import queue
import threading

import pytest

from ubitrack_agent.agent.announcements import provider_entries
from ubitrack_agent.agent.live_srg import LiveSrg
from ubitrack_agent.agent.planning import BackgroundPlanner, Outcome, Request, make_outcome
from ubitrack_agent.agent.replanning import Planned
from ubitrack_agent.graph.templates import load_templates
from ubitrack_agent.net.keys import KeySpace, RelationId

WAIT_S = 10.0
"""Longest wait for the planning thread in a test (a hung thread fails the test, not the run)."""


class Jobs:
    """A planning job that reports each request it starts and waits until released."""

    def __init__(self) -> None:
        self.started: queue.Queue[tuple[Request, Outcome | None]] = queue.Queue()
        self.release: queue.Queue[Exception | None] = queue.Queue()
        self.done = threading.Event()

    def __call__(self, request: Request, previous: Outcome | None) -> Outcome:
        self.started.put((request, previous))
        failure = self.release.get(timeout=WAIT_S)
        self.done.set()
        if failure is not None:
            raise failure
        return Outcome(request, LiveSrg(), Planned(), {}, {}, {}, {}, 0.0)

    def finish(self, failure: Exception | None = None) -> None:
        self.done.clear()
        self.release.put(failure)
        assert self.done.wait(WAIT_S)


def snapshot(generation: int, appeared: frozenset[str]) -> Request:
    return Request(generation, {}, frozenset(), frozenset(), frozenset(), True, appeared)


def settle(planner: BackgroundPlanner) -> Outcome | None:
    """Step until the finished job's result is taken (it is set just after the job returns)."""
    waiting = planner.in_flight
    for _ in range(1000):
        outcome = planner.step(snapshot)
        if planner.in_flight is not waiting:  # taken: applied, dropped (and asked again)
            return outcome
        threading.Event().wait(0.005)
    raise AssertionError("the planning thread never delivered")


@pytest.fixture
def jobs():
    made = Jobs()
    planner = BackgroundPlanner(made)
    yield made, planner
    planner.close()
    made.release.put(None)  # a job still waiting ends


def test_the_loop_does_not_wait_and_applies_a_current_outcome(jobs):
    job, planner = jobs
    assert planner.step(snapshot) is None  # submitted (generation 0), not waited for
    request, previous = job.started.get(timeout=WAIT_S)
    assert (request.generation, previous) == (0, None)
    for _ in range(3):
        assert planner.step(snapshot) is None  # the job still runs: nothing to apply
    job.finish()
    outcome = settle(planner)
    assert outcome is not None and outcome.request is request
    assert planner.applied == 0 and planner.in_flight is None
    assert planner.step(snapshot) is None and planner.in_flight is None  # up to date


def test_an_outcome_made_before_a_change_is_dropped_and_the_next_builds_on_it(jobs):
    job, planner = jobs
    planner.step(snapshot)
    first, _ = job.started.get(timeout=WAIT_S)
    planner.changed()  # an event while the plan is made
    planner.changed("fusion-1")  # a worker nothing ran
    job.finish()
    assert settle(planner) is None  # outdated: not applied
    assert planner.superseded == 1 and planner.applied == -1
    second, previous = job.started.get(timeout=WAIT_S)  # asked again at once, from the newest
    assert second.generation == 2 and second.appeared == {"fusion-1"}
    assert previous is not None and previous.request is first  # incremental from it
    job.finish()
    outcome = settle(planner)
    assert outcome is not None and outcome.request is second and planner.applied == 2


def test_a_failed_job_is_raised_on_the_loop_and_asked_again(jobs):
    job, planner = jobs
    planner.changed("fusion-1")
    planner.step(snapshot)
    first, _ = job.started.get(timeout=WAIT_S)
    assert first.appeared == {"fusion-1"}
    job.finish(RuntimeError("boom"))
    with pytest.raises(RuntimeError, match="boom"):
        settle(planner)
    assert planner.step(snapshot) is None  # asked again, keeping the worker that appeared
    again, previous = job.started.get(timeout=WAIT_S)
    assert again.appeared == {"fusion-1"}
    assert again.generation == first.generation and previous is None
    job.finish()
    assert settle(planner) is not None


def test_make_outcome_reuses_the_specifications_when_the_plan_did_not_change():
    keys = KeySpace("ubitrack/test")
    templates = load_templates()
    edges = [{"name": "HT", "from": "ART", "to": "HT", "type": "6D", "rate": 60}]
    fragments = {"art": provider_entries("art", edges, host="h1")}
    relation = RelationId("ART", "HT", "6D")
    request = Request(0, fragments, frozenset(), frozenset({relation}), frozenset(), True)
    first = make_outcome(request, None, templates, keys)
    assert first.data_hosts == {keys.data("art/HT"): "h1"}
    (relay,) = first.wanted.values()
    assert relay.service == "relay"
    again = make_outcome(request, first, templates, keys)
    assert again.planned.plan is first.planned.plan and again.wanted is first.wanted
    gone = make_outcome(
        Request(2, fragments, frozenset({"art/HT"}), request.relations, frozenset(), True),
        again,
        templates,
        keys,
    )
    assert gone.wanted == {} and "ART->HT:6D" in gone.planned.plan.unsolved


def test_a_finished_plan_wakes_the_loop():
    """The loop waits for events; the planning thread calls ``done`` once an outcome is ready,
    so the loop takes it at once rather than on its next pass (issue 28)."""
    job, woken = Jobs(), threading.Event()
    planner = BackgroundPlanner(job, done=woken.set)
    try:
        planner.step(snapshot)
        job.started.get(timeout=WAIT_S)
        assert not woken.is_set()  # not before the plan is made
        job.release.put(None)
        assert woken.wait(WAIT_S)
        assert planner.step(snapshot) is not None  # taken on that wake-up
    finally:
        planner.close()
