"""Frames on short simple ways (``ubitrack_agent/graph/ways.py``)."""

from __future__ import annotations

import itertools

import networkx as nx
from hypothesis import given, settings
from hypothesis import strategies as st

from ubitrack_agent.graph.ways import short_way_frames


def ring_with_hub(rooms: int) -> nx.Graph:
    """Rooms in a corridor (each surveyed to the next) and all surveyed to a building frame."""
    graph = nx.Graph()
    for r in range(rooms):
        graph.add_edge("B", f"R{r}")
        if r + 1 < rooms:
            graph.add_edge(f"R{r}", f"R{r + 1}")
    return graph


def frames_on_simple_paths(graph: nx.Graph, source: str, target: str, longest: int) -> set[str]:
    """The oracle: every simple path enumerated by networkx."""
    paths = nx.all_simple_paths(graph, source, target, cutoff=longest)
    return set(itertools.chain.from_iterable(paths)) | {source, target}


def test_near_a_hub_only_the_frames_on_short_simple_ways_are_kept():
    graph = ring_with_hub(50)
    frames = set(graph)
    # R0 - B - R49 is two hops; with two more, the ways go at most two rooms along the corridor
    kept = short_way_frames(graph.neighbors, frames, "R0", "R49", longest=4)
    assert kept == {"R0", "R1", "R2", "B", "R47", "R48", "R49"}
    assert kept == frames_on_simple_paths(graph, "R0", "R49", 4)


def test_the_region_is_kept_whole_when_the_ways_are_too_many_or_absent():
    graph = nx.complete_graph(9)
    frames = set(graph)
    assert short_way_frames(graph.neighbors, frames, 0, 1, longest=8, budget=100) == frames
    graph.add_node("alone")
    assert short_way_frames(graph.neighbors, frames | {"alone"}, 0, "alone", 3) == frames | {
        "alone"
    }


@settings(max_examples=200, deadline=None)
@given(
    edges=st.lists(st.tuples(st.integers(0, 7), st.integers(0, 7)), max_size=16),
    longest=st.integers(1, 6),
)
def test_the_frames_are_those_on_simple_paths_within_the_length(edges, longest):
    graph = nx.Graph()
    graph.add_nodes_from(range(8))
    graph.add_edges_from((a, b) for a, b in edges if a != b)
    frames = set(graph)
    kept = short_way_frames(graph.neighbors, frames, 0, 7, longest)
    if not nx.has_path(graph, 0, 7):
        assert kept == frames
    else:
        assert kept == frames_on_simple_paths(graph, 0, 7, longest)


def test_a_large_region_is_not_kept_whole_for_its_size_alone():
    """Around a hub of 6,000 rooms the enumeration takes more than ``DEFAULT_BUDGET`` steps
    (each of the hub's neighbours is tried); the budget grows with the region, so the short
    ways are still found."""
    graph = ring_with_hub(6000)
    frames = set(graph)
    kept = short_way_frames(graph.neighbors, frames, "R0", "R5999", longest=4)
    assert kept == {"R0", "R1", "R2", "B", "R5997", "R5998", "R5999"}
    fixed = short_way_frames(graph.neighbors, frames, "R0", "R5999", longest=4, budget=20_000)
    assert fixed == frames, "the old fixed budget gave up here"
