"""Incremental replanning (``agent/replanning.py``): an event replans only the relations it can
affect; every other relation keeps its plan object; the result equals planning everything."""

from __future__ import annotations

import pytest

from tests.unit.rooms import building, edge, tracker
from ubitrack_agent.agent.announcements import build_srg, provider_entries
from ubitrack_agent.agent.flows import plan_relations
from ubitrack_agent.agent.replanning import edge_changes, region_of, replan
from ubitrack_agent.agent.spares import Redundancy
from ubitrack_agent.graph.templates import load_templates
from ubitrack_agent.net.keys import RelationId

TEMPLATES = load_templates()


HEADS = [RelationId(f"H{r}_1", f"H{r}_2", "6D") for r in range(3)]


def running_of(planned):
    return set(planned.plan.flow.components)


def step(planned, fragments, relations, without=frozenset()):
    """Replan after an event, checking the incremental plan against planning everything."""
    srg = build_srg(fragments, without)
    running = running_of(planned) if planned else set()
    after = replan(planned, srg, TEMPLATES, relations, running)
    previous = planned.plan if planned else None
    everything = plan_relations(srg, TEMPLATES, relations, running, previous)
    assert after.plan.flow == everything.flow
    assert after.plan.unsolved.keys() == everything.unsolved.keys()
    assert after.plan.serving == everything.serving
    assert after.regions == {r: region_of(srg, TEMPLATES, r) for r in relations}  # all current
    return after


def kept(before, after, relations):
    return {r for r in relations if after.parts[r] is before.parts[r]}


def reads(planned, relation, provider):
    return any(e.startswith(f"{provider}/") for e in planned.parts[relation].edges)


def test_a_tracker_vanishing_in_one_room_replans_that_rooms_relation_only():
    fragments = building()
    first = step(None, fragments, HEADS)
    assert first.replanned == set(HEADS)
    assert reads(first, HEADS[0], "t0")
    del fragments["t0"]
    second = step(first, fragments, HEADS)
    assert second.replanned == {HEADS[0]}
    assert kept(first, second, HEADS) == set(HEADS[1:])
    assert reads(second, HEADS[0], "u0")


def test_a_new_edge_within_a_region_replans_it_and_nothing_else():
    fragments = building()
    del fragments["t1"]
    first = step(None, fragments, HEADS)
    assert reads(first, HEADS[1], "u1")
    fragments["t1"] = tracker("t1", 1)  # a better tracker appears in room 1
    second = step(first, fragments, HEADS)
    assert second.replanned == {HEADS[1]}
    assert kept(first, second, HEADS) == {HEADS[0], HEADS[2]}
    assert reads(second, HEADS[1], "t1")


def test_removing_an_edge_replans_the_relations_that_read_it_only():
    fragments = building()
    first = step(None, fragments, HEADS)
    assert first.plan.flow.spares["H0_1->H0_2:6D"]  # the worse tracker's way, for t0's loss
    assert reads(first, HEADS[0], "u0")
    unused = step(first, fragments, HEADS, without={"t0/room"})  # in room 0's region, unread
    assert unused.replanned == set()
    assert unused.plan is first.plan
    spare_lost = step(unused, fragments, HEADS, without={"t0/room", "u0/H1"})  # the spare's
    assert spare_lost.replanned == {HEADS[0]}
    assert "H0_1->H0_2:6D" not in spare_lost.plan.flow.spares  # none left
    assert spare_lost.parts[HEADS[0]].serving == first.parts[HEADS[0]].serving
    gone = {"t0/room", "u0/H1", "t0/H1"}
    used = step(spare_lost, fragments, HEADS, without=gone)  # read by H0_1->H0_2
    assert used.replanned == {HEADS[0]}
    assert kept(spare_lost, used, HEADS) == set(HEADS[1:])
    assert "H0_1->H0_2:6D" in used.plan.unsolved  # neither tracker sees H0_1 now
    back = step(used, fragments, HEADS, without={"t0/room", "u0/H1"})  # its data came back
    assert back.replanned == {HEADS[0]} and reads(back, HEADS[0], "t0")


def test_an_unsolved_relation_is_solved_when_its_frames_connect():
    fragments = building()
    lamp = RelationId("H2_1", "L", "6D")
    relations = [*HEADS, lamp]
    first = step(None, fragments, relations)
    assert "no provider announces frame(s) L" in first.plan.unsolved["H2_1->L:6D"]
    fragments["lamp"] = provider_entries("lamp", [edge("L", "X", "L", rate=10)])
    apart = step(first, fragments, relations)  # L now exists, not connected to the rooms
    assert "not connected" in apart.plan.unsolved["H2_1->L:6D"]
    assert kept(first, apart, HEADS) == set(HEADS)
    fragments["survey_x"] = provider_entries("survey_x", [edge("X", "R2", "X", static=True)])
    joined = step(apart, fragments, relations)
    assert "H2_1->L:6D" not in joined.plan.unsolved
    assert joined.replanned == {lamp}
    assert kept(apart, joined, HEADS) == set(HEADS)


def test_a_query_coming_or_going_plans_only_that_query():
    fragments = building()
    first = step(None, fragments, HEADS[:2])
    added = step(first, fragments, HEADS)
    assert added.replanned == {HEADS[2]}
    assert kept(first, added, HEADS[:2]) == set(HEADS[:2])
    gone = step(added, fragments, HEADS[1:])
    assert gone.replanned == set()
    assert kept(added, gone, HEADS[1:]) == set(HEADS[1:])
    assert "H0_1->H0_2:6D" not in gone.plan.relations


def test_a_relation_across_rooms_follows_changes_in_both_rooms_only():
    fragments = building()
    across = RelationId("H0_1", "H1_1", "6D")
    relations = [*HEADS, across]
    first = step(None, fragments, relations)
    fragments["u2"] = tracker("u2", 2, sigma=1e-4)  # better, in room 2: not on the way
    second = step(first, fragments, relations)
    assert second.replanned == {HEADS[2]}
    fragments["u1"] = tracker("u1", 1, sigma=1e-4)  # better, in room 1: on the way
    third = step(second, fragments, relations)
    assert third.replanned == {HEADS[1], across}
    assert reads(third, across, "u1")


def two_equal_trackers_in_room_0():
    """Room 0 seen by ``t0`` and ``v0``, equally good and so precise that fusing them is not
    worth a sensor: two derivations of ``H0_1 -> H0_2`` within the cost margin."""
    fragments = building()
    fragments["t0"] = tracker("t0", 0, sigma=1e-4)
    fragments["v0"] = tracker("v0", 0, sigma=1e-4)
    return fragments


@pytest.mark.parametrize("follow", [True, False])
def test_a_worker_appearing_replans_only_the_relations_it_may_serve(follow):
    srg = build_srg(two_equal_trackers_in_room_0())
    alone = Redundancy(spares=False)  # (with spares, the other derivation is the chosen's)
    first = replan(None, srg, TEMPLATES, HEADS, frozenset(), follow, redundancy=alone)
    chosen = first.parts[HEADS[0]]
    other = sorted(chosen.candidates - chosen.serving)  # the other tracker's derivation
    assert other and all(not first.parts[r].candidates & set(other) for r in HEADS[1:])
    running = frozenset(other)  # an earlier agent's workers of the other derivation appear
    again = replan(first, srg, TEMPLATES, HEADS, running, follow, running, redundancy=alone)
    assert again.replanned == {HEADS[0]}
    assert kept(first, again, HEADS) == set(HEADS[1:])
    previous = first.plan if follow else None
    everything = plan_relations(srg, TEMPLATES, HEADS, running, previous, alone)
    assert again.plan.flow == everything.flow and again.plan.serving == everything.serving
    # following its plan, the active agent keeps its choice; a standby moves onto what runs
    assert (again.parts[HEADS[0]].serving == chosen.serving) == follow
    assert (set(other) <= again.parts[HEADS[0]].serving) != follow


def test_a_worker_no_derivation_uses_replans_nothing():
    srg = build_srg(two_equal_trackers_in_room_0())
    first = replan(None, srg, TEMPLATES, HEADS, frozenset())
    stray = frozenset({"fusion-0123456789"})
    again = replan(first, srg, TEMPLATES, HEADS, stray, appeared=stray)
    assert again.replanned == set() and again.plan is first.plan


@pytest.mark.parametrize("recalibrate", [False, True])
def test_regions_and_changes(recalibrate):
    fragments = building()
    srg = build_srg(fragments)
    relation = RelationId("R0", "T0", "6D", static=True, recalibrate=recalibrate)
    region = region_of(srg, TEMPLATES, relation)
    assert {"R0", "T0"} <= region.frames and region.bound >= 1
    assert region_of(srg, TEMPLATES, RelationId("R0", "T0", "9D")).bound < 0  # never planned
    fragments["u0"] = tracker("u0", 0, sigma=2e-3)  # the same edges, another sigma
    removed, added = edge_changes(srg, build_srg(fragments))
    assert set(removed) == set(added) == {"u0/H1", "u0/H2"}
