"""Memoised plans (``agent/plan_memo.py``): answers equal to the planner's, reused while the
query's region is unchanged, planned again when an edge within it changes."""

from __future__ import annotations

import pytest

from tests.unit.rooms import building, edge, tracker
from ubitrack_agent.agent.announcements import build_srg, provider_entries
from ubitrack_agent.agent.plan_memo import PlanMemo, region_key
from ubitrack_agent.graph.planner import NoSolutionError, PlanningError, Query, plan
from ubitrack_agent.graph.templates import load_templates

TEMPLATES = load_templates()


QUERIES = [
    Query("H0_1", "H0_2", "6D"),
    Query("H1_1", "B", "6D"),
    Query("H0_1", "H2_2", "6D"),
    Query("R1", "H1_2", "6D", static=True),  # a body is not rigid in its room: no derivation
]


def same(a, b):
    """The same solutions: cost, steps and measured edges, in order."""
    return [(s.cost, s.as_json()) for s in a] == [(s.cost, s.as_json()) for s in b]


def answer(planner, srg, query, templates=TEMPLATES):
    try:
        return planner(srg, templates, query)
    except NoSolutionError as exc:
        return str(exc)


def test_memoised_answers_equal_the_planners_before_and_after_events():
    memo = PlanMemo()
    fragments = building()
    for event in (None, "u0", "t2", "u1"):
        if event:
            del fragments[event]
        srg = build_srg(fragments)
        for query in QUERIES:
            for _ in range(2):  # planned, then from the memo
                memoised, planned = answer(memo, srg, query), answer(plan, srg, query)
                assert type(memoised) is type(planned)
                assert memoised == planned if isinstance(planned, str) else same(memoised, planned)
    assert memo.hits >= memo.misses > 0


def test_an_event_outside_a_region_costs_no_plan_and_one_within_it_does():
    memo = PlanMemo()
    fragments = building()
    query = Query("H0_1", "H0_2", "6D")
    memo(build_srg(fragments), TEMPLATES, query)
    assert (memo.hits, memo.misses) == (0, 1)
    del fragments["u2"]  # another room
    memo(build_srg(fragments), TEMPLATES, query)
    assert (memo.hits, memo.misses) == (1, 1)
    del fragments["u0"]  # its room
    without = memo(build_srg(fragments), TEMPLATES, query)
    assert (memo.hits, memo.misses) == (1, 2)
    assert not any(e.provider == "u0" for s in without for e in s.measured())


def test_a_provider_coming_back_restores_the_plans_it_had():
    memo = PlanMemo()
    fragments = building()
    query = Query("H0_1", "B", "6D")
    before = memo(build_srg(fragments), TEMPLATES, query)
    gone = {p: e for p, e in fragments.items() if p != "t0"}
    memo(build_srg(gone), TEMPLATES, query)
    back = memo(build_srg(fragments), TEMPLATES, query)
    assert (memo.hits, memo.misses) == (1, 2)
    assert back[0] is before[0]  # the same solution object, not planned again


def test_the_key_changes_with_an_edges_attributes_within_the_region_only():
    fragments = building()
    query = Query("H0_1", "H0_2", "6D")
    key = region_key(build_srg(fragments), TEMPLATES, query)
    assert region_key(build_srg(fragments), TEMPLATES, query) == key
    fragments["t1"] = tracker("t1", 1, sigma=2e-3)
    assert region_key(build_srg(fragments), TEMPLATES, query) == key
    fragments["t0"] = tracker("t0", 0, sigma=2e-3)
    assert region_key(build_srg(fragments), TEMPLATES, query) != key


def test_absent_or_unconnected_frames_are_the_planners_errors_and_not_held():
    memo = PlanMemo()
    fragments = building()
    fragments["apart"] = provider_entries("apart", [edge("x", "X1", "X2", static=True)])
    srg = build_srg(fragments)
    for query in (Query("H0_1", "X", "6D"), Query("H0_1", "X2", "6D")):
        with pytest.raises(PlanningError) as memoised:
            memo(srg, TEMPLATES, query)
        with pytest.raises(PlanningError) as planned:
            plan(srg, TEMPLATES, query)
        assert str(memoised.value) == str(planned.value)
    assert len(memo) == 0


def test_the_least_recently_used_answer_goes_first():
    memo = PlanMemo(capacity=2)
    srg = build_srg(building())
    a, b, c = QUERIES[:3]
    for query in (a, b, a, c):  # c evicts b, the least recently used
        memo(srg, TEMPLATES, query)
    assert len(memo) == 2
    misses = memo.misses
    memo(srg, TEMPLATES, a)
    assert memo.misses == misses
    memo(srg, TEMPLATES, b)
    assert memo.misses == misses + 1
    with pytest.raises(ValueError):
        PlanMemo(capacity=0)


def test_other_templates_are_not_answered_from_the_memo():
    memo = PlanMemo()
    srg = build_srg(building())
    query = Query("H0_1", "B", "6D")
    memo(srg, TEMPLATES, query)
    other = list(TEMPLATES)  # another collection (its templates may differ): planned anew
    assert same(memo(srg, other, query), plan(srg, other, query))
    assert (memo.hits, memo.misses) == (0, 2)
    memo(srg, other, query)
    assert (memo.hits, memo.misses) == (1, 2)


def test_a_copy_answers_what_the_memo_held_and_counts_apart():
    memo = PlanMemo()
    srg = build_srg(building())
    a, b = QUERIES[:2]
    memo(srg, TEMPLATES, a)
    copy = memo.copy()
    copy(srg, TEMPLATES, a)
    copy(srg, TEMPLATES, b)
    assert (copy.hits, copy.misses, len(copy)) == (1, 2, 2)
    assert (memo.hits, memo.misses, len(memo)) == (0, 1, 1)


def test_a_region_that_changed_in_one_room_reuses_the_other_rooms_parts():
    memo = PlanMemo()
    fragments = building()
    query = Query("H0_1", "H2_2", "6D")  # across the building: parts at R0, B and R2
    memo(build_srg(fragments), TEMPLATES, query)
    saturated, reused = memo.parts.misses, memo.parts.hits
    assert (saturated, reused) == (3, 1)  # room 2 is equipped as room 0: room 0's part, renamed
    fragments["u0"] = tracker("u0", 0, sigma=4e-3)  # a better tracker in room 0 only
    srg = build_srg(fragments)
    assert same(memo(srg, TEMPLATES, query), plan(srg, TEMPLATES, query))
    assert memo.misses == 2  # the region changed: planned again,
    assert memo.parts.misses == saturated + 1  # but only room 0's part was saturated
    assert memo.parts.hits == reused + 3
