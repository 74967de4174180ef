"""``ubitrack status --dot``: labels escaped once, so Graphviz breaks the line where the label
says and shows no literal backslash-n (issue [surface])."""

from __future__ import annotations

import shutil
from types import SimpleNamespace

import pytest

from ubitrack_agent.commands.status import (
    draw_svg,
    flow_dot,
    live_dot,
    worker_statuses,
)
from ubitrack_agent.graph.dot import quote


def test_quote_escapes_once_and_keeps_line_breaks_as_dot_newlines():
    assert quote('a "b"\nc\\d') == '"a \\"b\\"\\nc\\\\d"'


def test_live_dot_breaks_component_labels_into_two_lines():
    status = {
        "key_prefix": "ubitrack/demo",
        "srg": [{"from": "ART", "to": "HT", "type": "6D", "static": False}],
        "components": {
            "fusion-1a": {"service": "fusion", "alive": True, "derives": [["C", "WT", "6D"]]}
        },
    }
    dot = live_dot(status)
    assert '[label="fusion 6D\\nfusion-1a", style=dashed' in dot
    assert "\\\\n" not in dot
    assert '"ART" -> "HT" [label="6D"];' in dot


ROOT = "ubitrack/demo"


def flow_status() -> dict:
    """The status of an agent running an inversion for two applications and a fusion."""
    root = ROOT
    return {
        "key_prefix": root,
        "providers": {"art": ["art/HT"]},
        "srg": [
            {"id": "art/HT", "from": "ART", "to": "HT", "type": "6D", "static": False, "rate": 60.0}
        ],
        "components": {
            "inversion-1": {
                "service": "inversion",
                "alive": True,
                "host": "room",
                "inputs": [{"key": f"{root}/data/art/HT"}],
                "outputs": {"BA": f"{root}/data/inversion-1/BA"},
                "relations": {"BA": [f"{root}/relation/HT/ART/6D/dynamic"]},
                "derives": [["HT", "ART", "6D"]],
            },
            "fusion-2": {
                "service": "fusion",
                "alive": False,
                "inputs": [{"key": f"{root}/data/inversion-1/BA"}, {"key": f"{root}/data/x/y"}],
                "outputs": {"fused": f"{root}/data/fusion-2/fused"},
                "relations": {},
                "derives": [["HT", "ART", "6D"]],
            },
        },
        "relations": {"HT->ART:6D": {"key": f"{root}/relation/HT/ART/6D/dynamic"}},
        "queries": {"HT->ART:6D": ["app1", "app2"]},
    }


def test_the_flow_picture_wires_sources_components_and_applications():
    root = ROOT
    dot = flow_dot(flow_status(), {"inversion-1": 59.6})
    assert '"provider art" [shape=house, label="art"];' in dot
    assert '"inversion-1" [shape=box, color=black, fontcolor=black, ' in dot
    assert 'label="inversion\\ninversion-1\\non room"];' in dot
    assert '"fusion-2" [shape=box, color=grey, fontcolor=grey' in dot  # still starting
    assert '"provider art" -> "inversion-1" [label="6D, 60 Hz"];' in dot
    assert '"inversion-1" -> "fusion-2" [label="6D, 60 Hz"];' in dot
    assert f'"{root}/data/x/y" -> "fusion-2" [label="?"];' in dot  # a producer not known
    assert '"application HT->ART:6D" [shape=invhouse, label="app1\\napp2\\nHT->ART:6D"];' in dot
    assert '"inversion-1" -> "application HT->ART:6D" [label="6D, 60 Hz"];' in dot
    assert "\\\\n" not in dot


def test_the_flow_picture_is_drawn_as_svg_by_graphviz(tmp_path):
    if shutil.which("dot") is None:
        pytest.skip("Graphviz's dot is not installed (Debian package graphviz)")
    path = tmp_path / "flow.svg"
    assert draw_svg(flow_dot(flow_status()), str(path)) is None
    assert "<svg" in path.read_text() and "inversion" in path.read_text()
    assert draw_svg("digraph {", str(tmp_path / "bad.svg"))  # Graphviz's complaint


class _Reply:
    def __init__(self, payload: bytes) -> None:
        self.ok = SimpleNamespace(
            payload=SimpleNamespace(to_bytes=lambda: payload), attachment=None
        )


class _Session:
    """Answers a get with the given worker status payloads."""

    def __init__(self, *payloads: bytes) -> None:
        self.payloads = payloads

    def get(self, key: str, timeout: float) -> list[_Reply]:
        return [_Reply(payload) for payload in self.payloads]


def test_worker_statuses_leave_out_replies_that_are_no_worker_status():
    session = _Session(
        b'{"instance": "fusion-1", "counters": {"published": 3}, '
        b'"latency_ms": {"k": 4.5, "nan": NaN, "s": "x", "big": 1e999}}',
        b'{"instance": "relay-1", "counters": {}, "latency_ms": [1]}',
        b"not json",
        b"[" * 100_000,
        b"[1]",
        b'{"instance": 5, "counters": {}}',
        b'{"instance": "x", "counters": 7}',
    )
    keys = SimpleNamespace(all_statuses=lambda: "ubitrack/demo/status/*")
    assert worker_statuses(session, keys, 0.1) == {
        "fusion-1": {"counters": {"published": 3}, "latency_ms": {"k": 4.5}},
        "relay-1": {"counters": {}, "latency_ms": {}},
    }


def test_wires_carry_the_latency_their_consumer_measures_on_the_agents_clock():
    status = flow_status()
    inversion, fusion = status["components"]["inversion-1"], status["components"]["fusion-2"]
    inversion["latency_ms"] = {f"{ROOT}/data/art/HT": 6.4}
    assert '"provider art" -> "inversion-1" [label="6D, 60 Hz, 6 ms"];' in flow_dot(status)
    # A fusion on a host 200 ms ahead, its first input put on the agent's clock: the worker
    # measured 205 ms on its own clock; the host's offset (-200 ms) brings it to 5 ms.
    fusion["host"] = "hmd"
    fusion["inputs"][0]["clock_offset_ns"] = -200_000_000
    fusion["latency_ms"] = {f"{ROOT}/data/inversion-1/BA": 205.0}
    status["host_info"] = {"hmd": {"clock": {"offset_ns": -200_000_000}}}
    assert '"inversion-1" -> "fusion-2" [label="6D, 5 ms"];' in flow_dot(status)
    status["host_info"] = {}  # the offset not known: no figure rather than a wrong one
    assert '"inversion-1" -> "fusion-2" [label="6D"];' in flow_dot(status)


def test_a_component_is_named_by_its_pattern_when_the_status_has_one():
    status = flow_status()
    status["components"]["inversion-1"]["pattern"] = "Inversion"
    assert 'label="Inversion\\ninversion-1\\non room"' in flow_dot(status)
    assert 'label="fusion\\nfusion-2"' in flow_dot(status)  # no pattern: its service


def test_a_static_relation_is_drawn_with_its_applications():
    """The status names a static query and its relation alike: ``C->HT:6D/static``."""
    status = flow_status()
    status["relations"] = {"HT->ART:6D/static": status["relations"].pop("HT->ART:6D")}
    status["queries"] = {"HT->ART:6D/static": ["calibrate"]}
    assert 'label="calibrate\\nHT->ART:6D/static"];' in flow_dot(status)
