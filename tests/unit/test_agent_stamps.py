"""The agent's stamps of each step from a query to its components (``agent/stamps.py``)."""

from __future__ import annotations

from ubitrack_agent.agent.stamps import Stamps


def test_a_query_keeps_the_first_time_of_each_step_until_it_is_withdrawn():
    stamps = Stamps()
    stamps.query("C->A:6D", "app1", "received_ns", 10)
    stamps.query("C->A:6D", "app1", "received_ns", 20)  # seen again: the first time stays
    stamps.query("C->A:6D", "app2", "received_ns", 15)
    assert stamps.unplanned("C->A:6D") == [{"received_ns": 10}, {"received_ns": 15}]
    stamps.unplanned("C->A:6D")[0]["planned_ns"] = 30  # the first plan serving it
    assert stamps.unplanned("C->A:6D") == [{"received_ns": 15}]
    assert stamps.unplanned("X->Y:6D") == []
    stamps.forget_query("C->A:6D", "app2")
    assert stamps.as_dict()["queries"] == {
        "C->A:6D": {"app1": {"received_ns": 10, "planned_ns": 30}}
    }
    stamps.forget_query("C->A:6D", "app1")
    assert stamps.as_dict()["queries"] == {}


def test_a_component_keeps_its_latest_times_while_wanted():
    stamps = Stamps()
    stamps.component("a", "requested_ns", 1)
    stamps.component("a", "requested_ns", 5)  # started again: the latest request
    stamps.component("b", "rewired_ns", 2)
    stamps.keep_components({"a"})
    assert stamps.as_dict()["components"] == {"a": {"requested_ns": 5}}
