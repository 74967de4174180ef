"""One active agent per domain (``agent.election``): the rule applied to the tokens seen."""

from __future__ import annotations

import time

from ubitrack_agent.agent.election import TAKEOVER_STEP_S, Election, new_agent_id


def test_ids_sort_by_start_time():
    first = new_agent_id()
    time.sleep(0.001)
    assert first < new_agent_id()
    assert len(first.split(".")[0]) == 16  # fixed width: sorted as text, ordered by time


def test_nothing_is_decided_before_start_up_settles():
    alone = Election("b")
    assert not alone.should_be_active(False, settled=False, now=0.0)
    assert alone.should_be_active(False, settled=True, now=0.1)


def test_of_two_agents_starting_together_the_first_becomes_active():
    first, second = Election("a"), Election("b")
    first.member("b", True)
    second.member("a", True)
    assert first.should_be_active(False, True, now=0.0)
    assert not second.should_be_active(False, True, now=0.0)
    second.active("a", True)  # the first one's active token arrives within the step
    assert not second.should_be_active(False, True, now=TAKEOVER_STEP_S)


def test_a_standby_takes_over_at_once_when_the_active_agent_vanishes():
    standby = Election("b")
    standby.active("a", True)
    assert not standby.should_be_active(False, True, now=0.0)
    standby.member("a", False)  # the active agent's process ended: both tokens go
    assert standby.actives == set() and standby.members == {"b"}
    assert standby.should_be_active(False, True, now=0.01)


def test_the_next_standby_waits_a_step_for_the_first():
    third = Election("c")
    for agent in ("a", "b"):
        third.member(agent, True)
    third.active("a", True)
    assert not third.should_be_active(False, True, now=0.0)
    third.member("a", False)
    assert not third.should_be_active(False, True, now=1.0)  # "b" comes first
    assert not third.should_be_active(False, True, now=1.0 + 0.9 * TAKEOVER_STEP_S)
    assert third.should_be_active(False, True, now=1.0 + TAKEOVER_STEP_S)  # "b" hangs
    other = Election("c", members={"b"})
    other.should_be_active(False, True, now=0.0)
    other.active("b", True)  # "b" takes over in time: "c" stays a standby
    assert not other.should_be_active(False, True, now=5 * TAKEOVER_STEP_S)


def test_an_active_agent_stays_active_when_an_earlier_standby_joins():
    active = Election("b")
    assert active.should_be_active(False, True, now=0.0)
    active.member("a", True)  # a clock set back, say: "a" sorts first but is not active
    assert active.should_be_active(True, True, now=1.0)
    late = Election("a", members={"b"})
    late.active("b", True)
    assert not late.should_be_active(False, True, now=1.0)


def test_of_two_active_agents_the_later_steps_down():
    later, earlier = Election("b"), Election("a")
    later.active("a", True)
    earlier.active("b", True)
    assert not later.should_be_active(True, True, now=0.0)
    assert earlier.should_be_active(True, True, now=0.0)


def test_its_own_tokens_do_not_make_an_agent_step_down():
    own = Election("a")
    own.active("a", True)
    own.member("a", False)  # never removed: its own token goes only when the process ends
    assert own.should_be_active(True, True, now=0.0)
    assert own.members == {"a"}
    assert own.standbys == []
