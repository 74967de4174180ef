"""Data liveness observed where the data is: the provider's rule for a quiet edge
(``io/provider.py``) and the agent's handling of the providers' reports (``agent/liveness.py``),
total on any bytes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ubitrack_agent.agent.liveness import ProviderReports, ReportError, parse_report
from ubitrack_agent.io.provider import QuietEdges, stale_after


def test_which_edges_are_watched_and_their_windows():
    assert stale_after(False, "push", 100.0) == 1.0  # max(20 / 100, 1)
    assert stale_after(False, "push", 0.5) == 40.0
    assert stale_after(True, "push", 100.0) is None  # static
    assert stale_after(False, "pull", 100.0) is None
    assert stale_after(False, "push", None) is None
    assert stale_after(False, "push", 0.0) is None


def checked_until(edges: QuietEdges, start: float, end: float) -> frozenset[str]:
    """The quiet edges at ``end``, checked every 50 ms from ``start`` as the provider does."""
    for now in np.arange(start, end, 0.05):
        edges.check(float(now))
    edges.check(end)
    return edges.quiet


def test_an_edge_without_samples_for_its_window_is_quiet_until_one_is_published():
    edges = QuietEdges({"HT": 1.0, "slow": 40.0}, now=0.0)
    assert checked_until(edges, 0.0, 0.9) == frozenset()  # a new edge has its window
    assert checked_until(edges, 0.9, 1.1) == {"HT"}
    assert edges.published("HT", 1.2)  # back: the provider reports at once
    assert edges.quiet == frozenset()
    assert not edges.published("HT", 1.21) and not edges.published("WT", 1.21)  # unwatched
    assert checked_until(edges, 1.2, 2.1) == frozenset()
    assert checked_until(edges, 2.1, 41.0) == {"HT", "slow"}


def test_a_pause_of_the_provider_is_not_silence_of_its_edges():
    edges = QuietEdges({"HT": 1.0}, now=0.0)
    assert checked_until(edges, 0.0, 0.5) == frozenset()
    assert not edges.check(3.0)  # no check for 2.5 s: the provider did not run
    edges.published("HT", 3.05)  # samples queued meanwhile are published
    assert checked_until(edges, 3.0, 4.0) == frozenset()
    assert checked_until(edges, 4.0, 4.1) == {"HT"}  # then silence counts again


ENTRIES = [{"id": "art/HT"}, {"id": "art/WT"}]


def report(*names: str) -> bytes:
    return json.dumps({"quiet": list(names)}).encode()


def test_reports_make_edges_stale_and_back():
    reports = ProviderReports()
    reports.take("art", parse_report(report("HT")), ENTRIES)
    assert reports.stale == {"art/HT"}
    reports.take("ir", parse_report(report("X")), [{"id": "ir/X"}])
    assert reports.stale == {"art/HT", "ir/X"}
    reports.take("art", parse_report(report()), ENTRIES)
    assert reports.stale == {"ir/X"}
    reports.forget("ir")
    assert reports.stale == frozenset()


@pytest.mark.parametrize(
    "payload",
    [
        b"",
        b"\xff\xfe",
        b"[]",
        b'{"quiet": "HT"}',
        b'{"quiet": ["HT"], "more": 1}',
        b'{"quiet": [1]}',
        b'{"quiet": ["a/b"]}',
        b'{"quiet": ["*"]}',
        b'{"quiet": [' + b",".join([b'"e"'] * 1001) + b"]}",
        b"[" * 100_000,
        b" " * (64 * 1024 + 1),
    ],
)
def test_malformed_reports_are_refused_with_a_reason(payload):
    with pytest.raises(ReportError) as refused:
        parse_report(payload)
    assert str(refused.value)


def test_a_report_naming_edges_the_provider_does_not_announce_is_refused():
    reports = ProviderReports()
    reports.take("art", parse_report(report("HT")), ENTRIES)
    with pytest.raises(ReportError, match="does not announce"):
        reports.take("art", parse_report(report("HT", "ir_HT")), ENTRIES)
    assert reports.stale == {"art/HT"}  # the previous report stands
