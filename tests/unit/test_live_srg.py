"""The live SRG assembled from fragments parsed once (``agent/live_srg.py``): the same SRG as
``build_srg`` and the same changes as comparing the SRGs, through a sequence of events."""

from __future__ import annotations

from ubitrack_agent.agent.announcements import build_srg, provider_entries
from ubitrack_agent.agent.live_srg import live_srg
from ubitrack_agent.agent.replanning import edge_changes


def edges_of(srg):
    return [(u, v, key, data) for u, v, key, data in srg.edges(keys=True, data=True)]


def tracker(name, sigma=1e-3):
    edges = [
        {"name": "room", "from": "R", "to": name.upper(), "type": "6D", "static": True},
        {"name": "H", "from": name.upper(), "to": "H", "type": "6D", "rate": 60, "sigma": sigma},
    ]
    return provider_entries(name, edges)


def test_the_live_srg_and_its_changes_match_building_and_comparing_everything():
    a, b = tracker("a"), tracker("b")
    events = [
        ({"a": a}, frozenset()),
        ({"a": a, "b": b}, frozenset()),  # a provider appears
        ({"a": a, "b": b}, frozenset({"a/H"})),  # an edge goes stale
        ({"a": tracker("a", 2e-3), "b": b}, frozenset({"a/H"})),  # announced again, changed
        ({"a": a, "b": b}, frozenset({"b/H"})),  # one back, another stale, a changed back
        ({"b": b}, frozenset({"b/H"})),  # a provider vanishes
        ({"b": b}, frozenset()),
        ({}, frozenset()),
    ]
    previous, before = None, build_srg({})
    for fragments, stale in events:
        live, removed, added = live_srg(fragments, stale, previous)
        expected = build_srg(fragments, without=stale)
        assert edges_of(live.srg) == edges_of(expected)
        assert live.srg.graph["edge_index"] == expected.graph.get("edge_index", {})
        assert (removed, added) == edge_changes(before, expected)
        previous, before = live, expected


def test_a_fragment_is_parsed_once():
    a = tracker("a")
    first, _, _ = live_srg({"a": a}, frozenset())
    second, removed, added = live_srg({"a": a, "b": tracker("b")}, frozenset(), first)
    assert second.parsed["a"] is first.parsed["a"]
    assert not removed and set(added) == {"b/room", "b/H"}


def test_nothing_changed_gives_the_same_srg_object():
    a = tracker("a")
    first, _, _ = live_srg({"a": a}, frozenset({"a/H"}))
    again, removed, added = live_srg({"a": a}, frozenset({"a/H"}), first)
    assert again is first and not removed and not added
    back, removed, added = live_srg({"a": a}, frozenset(), first)
    assert back.srg is not first.srg and set(added) == {"a/H"} and not removed
