"""Incremental replanning (``agent/replanning.py``): an event replans only the relations it can
affect; every other relation keeps its plan object; the result equals planning everything."""

from __future__ import annotations

import pytest

from ubitrack_agent.agent.announcements import build_srg, provider_entries
from ubitrack_agent.agent.flows import plan_relations
from ubitrack_agent.agent.replanning import edge_changes, region_of, replan
from ubitrack_agent.graph.templates import load_templates
from ubitrack_agent.net.keys import RelationId

TEMPLATES = load_templates()


def edge(name, source, target, edge_type="6D", **extra):
    return {"name": name, "from": source, "to": target, "type": edge_type, **extra}


def tracker(name, room, sigma=1e-3):
    """A tracker ``name`` in ``room`` seeing the room's two bodies ``H<room>_1``, ``_2``."""
    frame = name.upper()
    return provider_entries(
        name,
        [
            edge("room", f"R{room}", frame, static=True),
            *(edge(f"H{j}", frame, f"H{room}_{j}", rate=60, sigma=sigma) for j in (1, 2)),
        ],
    )


def building(rooms=3):
    """Rooms ``R<r>`` surveyed into ``B``, each with tracker ``t<r>`` and a worse ``u<r>``."""
    fragments = {
        "survey": provider_entries(
            "survey", [edge(f"R{r}", "B", f"R{r}", static=True) for r in range(rooms)]
        )
    }
    for r in range(rooms):
        fragments[f"t{r}"] = tracker(f"t{r}", r)
        fragments[f"u{r}"] = tracker(f"u{r}", r, sigma=5e-3)
    return fragments


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
    unused = step(first, fragments, HEADS, without={"u0/H1"})  # in room 0's region, unread
    assert unused.replanned == set()
    assert unused.plan is first.plan
    used = step(unused, fragments, HEADS, without={"u0/H1", "t0/H1"})  # read by H0_1->H0_2
    assert used.replanned == {HEADS[0]}
    assert kept(unused, used, HEADS) == set(HEADS[1:])
    assert "H0_1->H0_2:6D" in used.plan.unsolved  # neither tracker sees H0_1 now
    back = step(used, fragments, HEADS, without={"u0/H1"})  # its data came back
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


def test_full_replans_everything_and_a_worker_preference_is_kept():
    fragments = building()
    first = step(None, fragments, HEADS)
    srg = build_srg(fragments)
    again = replan(first, srg, TEMPLATES, HEADS, running_of(first), full=True)
    assert again.replanned == set(HEADS)
    assert again.plan.flow == first.plan.flow


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
