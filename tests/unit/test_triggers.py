"""Held triggers: released when inputs catch up or the wait is over, in order, once each."""

from services.triggers import PendingTriggers


def test_trigger_waits_for_inputs_then_releases_in_order():
    pending = PendingTriggers(wait_s=0.005)
    assert pending.add(100, now=0.0)
    assert pending.add(200, now=0.001)
    assert not pending.add(100, now=0.002)  # the same instant from another binding
    caught_up_to = 150
    assert pending.due(now=0.001, caught_up=lambda t: t <= caught_up_to) == [100]
    assert pending.due(now=0.002, caught_up=lambda t: t <= caught_up_to) == []
    assert pending.next_deadline() == 0.006
    assert pending.due(now=0.0061, caught_up=lambda t: False) == [200]  # waited long enough
    assert not pending.add(150, now=0.01)  # older than an instant already computed
    assert len(pending) == 0


def test_a_waiting_trigger_holds_back_later_ones():
    pending = PendingTriggers(wait_s=1.0)
    pending.add(1, now=0.0)
    pending.add(2, now=0.0)
    assert pending.due(now=0.5, caught_up=lambda t: t == 2) == []
    assert pending.due(now=1.0, caught_up=lambda t: t == 2) == [1, 2]
