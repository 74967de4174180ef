"""Which of a provider's edges deliver (``io.flowing``): pure, times passed in."""

from hypothesis import given
from hypothesis import strategies as st

from bench.flowing_bench import one_size
from ubitrack_agent.io.flowing import (
    INTERVALS_NEEDED,
    LATE_MIN_S,
    MISSED_IN_ROW,
    SILENT_INTERVALS,
    FlowingEdges,
)

PERIOD = 1 / 60


def publishing(edges: FlowingEdges, name: str, count: int, start: float = 0.0) -> float:
    """``count`` samples of ``name`` a period apart from ``start``; the last one's time."""
    now = start
    for i in range(count):
        now = start + i * PERIOD
        edges.published(name, now)
    return now


def test_an_edge_flows_from_its_first_sample_and_stops_two_intervals_after_its_last():
    edges = FlowingEdges(["HT", "WT"])
    assert edges.published("HT", 0.0) is True  # starts flowing: its token is declared
    assert edges.published("HT", PERIOD) is False
    assert edges.flowing == {"HT"}
    assert [edges.published("HT", i * PERIOD) for i in range(2, 5)] == [False, True, False]
    # True when its rate became known: the checker looks for its first deadline
    last = publishing(edges, "HT", 10)
    assert abs(edges.deadline("HT") - (last + SILENT_INTERVALS * PERIOD)) < 1e-12
    assert edges.silent(last + 2.4 * PERIOD) == ([], edges.deadline("HT"))
    assert edges.silent(last + 2.5 * PERIOD + 1e-9)[0] == ["HT"]
    assert edges.flowing == set()
    assert edges.published("HT", last + 0.5) is True  # back: declared again


def test_a_dropped_sample_now_and_then_neither_stops_an_edge_nor_lengthens_its_interval():
    edges = FlowingEdges(["HT"])
    times = [i * PERIOD for i in range(12) if i != 6]  # one frame dropped
    for now in times:
        assert edges.silent(now - 1e-9)[0] == []  # the sample after the drop is in time
        edges.published("HT", now)
    assert abs(edges.deadline("HT") - (times[-1] + SILENT_INTERVALS * PERIOD)) < 1e-12


def test_an_edge_whose_rate_is_not_known_yet_is_not_judged_silent():
    edges = FlowingEdges(["HT"])
    publishing(edges, "HT", INTERVALS_NEEDED)  # INTERVALS_NEEDED - 1 intervals
    assert edges.deadline("HT") is None
    assert edges.silent(100.0) == ([], None)
    assert edges.flowing == {"HT"}


def test_a_fast_edge_stops_only_once_a_sample_is_late_by_the_least_lateness():
    edges = FlowingEdges(["F"])
    for i in range(10):
        edges.published("F", i * 0.001)  # a kilohertz
    assert abs(edges.deadline("F") - (0.009 + 0.001 + LATE_MIN_S)) < 1e-12


def test_an_edge_left_out_of_two_frames_in_a_row_stops_and_unwatched_edges_are_ignored():
    assert MISSED_IN_ROW == 2
    edges = FlowingEdges(["HT"])
    assert [edges.missed("HT"), edges.missed("HT")] == [False, False]  # not flowing
    edges.published("HT", 0.0)
    assert edges.missed("HT") is False  # one frame left out: a drop
    edges.published("HT", PERIOD)
    assert edges.missed("HT") is False and edges.flowing == {"HT"}  # not in a row
    assert edges.missed("HT") is True and edges.flowing == set()
    assert edges.missed("nope") is False
    assert edges.published("static", 0.0) is False and not edges.watches("static")
    assert edges.flowing == set()


def test_the_next_check_is_never_after_a_deadline_and_moves_on_with_the_samples():
    edges = FlowingEdges(["slow", "fast"])
    for i in range(6):
        edges.published("slow", i * 0.1)
        edges.published("fast", i * 0.01)
    stopped, next_check = edges.silent(0.5)
    # slow's deadline as it was when its rate became known: a check then moves it on
    assert stopped == ["fast"] and next_check == 0.3 + SILENT_INTERVALS * 0.1
    assert edges.silent(next_check) == ([], edges.deadline("slow"))


@given(
    st.lists(
        st.tuples(st.sampled_from(["a", "b", "c"]), st.floats(0.0, 0.2), st.booleans()),
        max_size=60,
    )
)
def test_flowing_is_exactly_the_edges_published_since_they_last_stopped(steps):
    """Whatever the order of samples, frames without an edge and checks: an edge flows iff
    it was published after it last stopped (two frames in a row without it, or a check past
    its deadline), a check stops only edges past their deadline, and there is a next check
    while an edge with a known rate flows (an edge whose rate rose is checked by the deadline
    of its slower rate, a little late: never early)."""
    edges, now, published_since_stop = FlowingEdges(["a", "b", "c"]), 0.0, set()
    left_out_in_row = dict.fromkeys("abc", 0)
    for name, wait, miss in steps:
        now += wait
        if miss:
            edges.missed(name)
            left_out_in_row[name] += 1
            if left_out_in_row[name] >= MISSED_IN_ROW:
                published_since_stop.discard(name)
        else:
            edges.published(name, now)
            left_out_in_row[name] = 0
            published_since_stop.add(name)
        due = {n: edges.deadline(n) for n in edges.flowing}
        stopped, next_check = edges.silent(now)
        assert all(due[n] is not None and due[n] <= now for n in stopped)
        published_since_stop.difference_update(stopped)
        assert edges.flowing == published_since_stop
        later = [d for n, d in due.items() if n not in stopped and d is not None]
        if later:  # the provider never sleeps for good while an edge can stop
            assert next_check is not None and next_check > now


def test_a_jittery_stream_with_dropped_frames_raises_no_false_alarm_and_few_checks():
    """The bench's stream (``bench.flowing_bench``: 60 Hz, 2 ms of jitter, 2 % of frames
    dropped) for 20 edges: no edge is judged silent while it delivers, and there are about
    half as many checks as samples (each edge comes due about every two intervals)."""
    size = one_size(edges=20, seconds=3.0, rate=60.0, seed=3)
    assert size["false_alarms"] == 0
    assert 0.4 * size["samples"] < size["checks"] < 0.6 * size["samples"]
