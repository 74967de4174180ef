"""``ubitrack view``'s HTTP answers and the snapshot they are made from: every request gets an
answer (bad paths, methods and queries a 4xx), the agent's status is read as untrusted input,
and the page needs nothing from outside the view."""

from __future__ import annotations

import json
import re

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.unit.test_status_dot import flow_status
from ubitrack_agent.commands.view.frame_watch import frames_from
from ubitrack_agent.commands.view.pages import PATHS, Pages
from ubitrack_agent.commands.view.snapshot import (
    MAX_RELATIONS,
    Snapshot,
    StatusError,
    enrich,
    output_rates,
    parse_status,
    pattern_names,
    relation_rows,
    watched_relations,
)
from ubitrack_agent.graph.templates import load_templates
from ubitrack_agent.net.keys import KeySpace, RelationId

KEYS = KeySpace("ubitrack/demo")
FIELDS = (
    *("key_prefix", "agent", "providers", "srg", "components", "relations", "queries"),
    *("unsolved", "id", "from", "to", "type", "static", "rate", "service", "alive", "host"),
    *("inputs", "outputs", "derives", "key", "pattern"),
)
"""Names the agent's status uses, so that generated statuses reach deep into the drawing."""
NO_AGENT = Snapshot(1, None, "no agent answers on ubitrack/demo/agent/status")


class Drawing:
    """A stand-in for Graphviz that counts its drawings."""

    def __init__(self, failure: str | None = None) -> None:
        self.drawn: list[str] = []
        self.failure = failure

    def __call__(self, dot: str) -> tuple[str | None, str | None]:
        self.drawn.append(dot)
        return (None, self.failure) if self.failure else ("<svg>flow</svg>", None)


def pages(snapshot: Snapshot, drawing: Drawing | None = None) -> Pages:
    """The pages of ``snapshot``; its frames placed from its status's SRG, with no samples."""
    srg = (snapshot.status or {}).get("srg")
    srg = srg if isinstance(srg, list) else []
    return Pages(
        lambda: snapshot,
        drawing or Drawing(),
        every_s=1.0,
        frames=lambda root: frames_from(srg, {}, {}, root),
    )


def running() -> Snapshot:
    status = enrich(flow_status(), {"inversion-1": {"published": 7}}, {}, {"inversion": "Inv"})
    return Snapshot(2, status, rates={"inversion-1": 59.6}, relations={"HT->ART:6D": {}})


@pytest.mark.parametrize(
    ("method", "path", "query", "code"),
    [
        ("GET", "/nowhere", "", 404),
        ("GET", "/status.json/", "", 404),
        ("GET", "/../etc/passwd", "", 404),
        ("GET", "/" + "x" * 10_000, "", 404),
        ("GET", "/\x00", "", 404),
        ("POST", "/", "", 405),
        ("DELETE", "/status.json", "", 405),
        ("GET", "/", "t=1", 400),
        ("GET", "/status.json", "x", 400),
        ("GET", "/flow.svg", "%ff%00", 400),
        ("GET", "/flow.json", "x=1", 400),
        ("GET", "/frames.json", "x=1", 400),
        ("GET", "/frames.json", "root=ART&root=HT", 400),
        ("GET", "/frames.json", "root=ART&x=1", 400),
        ("GET", "/frames.json", "root", 400),
        ("GET", "/frames.json", "&" * 5000, 400),
        ("GET", "/frames.json", "root=NOPE", 404),
        ("GET", "/frames.json", "root=" + "x" * 10_000, 404),
    ],
)
def test_bad_requests_get_a_client_error(method, path, query, code):
    reply = pages(running()).respond(method, path, query)
    assert reply.status == code
    assert len(reply.body) < 1000  # a bad path is not echoed at length


def test_every_path_answers_and_every_answer_has_the_security_headers():
    view = pages(running())
    for path in PATHS:
        for method in ("GET", "HEAD"):
            reply = view.respond(method, path, "")
            assert reply.status == 200, (path, reply.body)
            headers = reply.all_headers()
            assert headers["Cache-Control"] == "no-store"
            assert "script-src 'self'" in headers["Content-Security-Policy"]


def test_status_json_is_the_enriched_status_or_why_there_is_none():
    reply = pages(running()).respond("GET", "/status.json", "")
    component = json.loads(reply.body)["components"]["inversion-1"]
    assert (component["pattern"], component["counters"]) == ("Inv", {"published": 7})
    reply = pages(NO_AGENT).respond("GET", "/status.json", "")
    assert reply.status == 503
    assert json.loads(reply.body) == {"error": "no agent answers on ubitrack/demo/agent/status"}


def test_series_json_holds_the_relations_and_the_views_counters():
    reply = pages(running()).respond("GET", "/series.json", "")
    assert json.loads(reply.body) == {
        "taken_ns": 2,
        "every_s": 1.0,
        "relations": {"HT->ART:6D": {}},
        "counters": {},
    }


def test_the_flow_is_drawn_once_per_change_and_named_by_pattern():
    drawing = Drawing()
    view = pages(running(), drawing)
    dot = view.respond("GET", "/flow.dot", "")
    assert dot.status == 200 and 'label="Inv\\ninversion-1\\non room"' in dot.body.decode()
    assert '"inversion-1" -> "fusion-2" [label="6D, 60 Hz"]' in dot.body.decode()
    for _ in range(3):
        svg = view.respond("GET", "/flow.svg", "")
        assert (svg.status, svg.content_type) == (200, "image/svg+xml")
        assert svg.body == b"<svg>flow</svg>"
    assert drawing.drawn == [dot.body.decode()]  # drawn once for an unchanged flow


def test_without_graphviz_or_an_agent_the_flow_says_why():
    missing = pages(running(), Drawing("Graphviz's dot is not installed"))
    reply = missing.respond("GET", "/flow.svg", "")
    assert reply.status == 503 and b"not installed" in reply.body
    assert missing.respond("GET", "/flow.dot", "").status == 200  # the page shows the DOT
    for path in ("/flow.svg", "/flow.dot"):
        reply = pages(NO_AGENT).respond("GET", path, "")
        assert reply.status == 503 and b"no agent answers" in reply.body


@pytest.mark.parametrize(
    "status",
    [
        {"key_prefix": "r", "components": {"a": {"no": "service"}}},
        {"key_prefix": "r", "components": {"a": {"service": "s", "inputs": [3]}}},
        {"key_prefix": "r", "providers": {"p": 5}},
        {"components": {}},
        {"key_prefix": "r", "relations": {"x": {"key": "k"}}, "components": {"a": 1}},
    ],
)
def test_a_status_that_cannot_be_drawn_is_a_bad_gateway(status):
    view = pages(Snapshot(3, status))
    for path in ("/flow.svg", "/flow.dot", "/flow.json"):
        reply = view.respond("GET", path, "")
        assert reply.status == 502 and b"cannot be drawn" in reply.body


def test_the_pages_need_nothing_from_outside_the_view():
    view = pages(NO_AGENT)
    for path in ("/", "/view.js", "/view.css", "/3d", "/view3d.js"):
        text = view.respond("GET", path, "").body.decode()
        outside = re.findall(r"(?:https?:)?//[\w.-]+", text)
        assert set(outside) <= {"http://www.w3.org"}, (path, outside)  # the SVG namespace
        loaded = re.findall(r'(?:src|href)="([^"]+)"|from "([^"]+)"', text)
        for name in {part for parts in loaded for part in parts if part}:
            assert view.respond("GET", name.split("#")[0], "").status == 200, (path, name)
    for path in ("/view.js", "/view3d.js"):
        script = view.respond("GET", path, "").body.decode()
        assert "innerHTML" not in script and "eval(" not in script  # network text stays text
    module = view.respond("GET", "/vendor/three/three.module.min.js", "").body.decode()
    assert set(re.findall(r'from\s*"([^"]+)"', module)) == {"./three.core.min.js"}  # beside it
    for library in ("dagre", "three"):
        assert (
            b"Permission is hereby granted"
            in view.respond("GET", f"/vendor/{library}/LICENSE", "").body
        )


def test_the_status_is_read_as_untrusted_input():
    assert parse_status(b'{"agent": {"id": "a"}}') == {"agent": {"id": "a"}}
    for payload in (b"not json", b"\xff\xfe", b"[1, 2]", b'{"a": NaN}', b'{"a": 1e999}'):
        with pytest.raises(StatusError):
            parse_status(payload)
    with pytest.raises(StatusError):
        parse_status(b"[" * 100_000 + b"]" * 100_000)  # nested too deep


def test_enrich_adds_pattern_counters_and_rate_and_leaves_odd_components_alone():
    status = {"components": {"a": {"service": "fusion"}, "b": "odd", "c": {"service": 3}}}
    patterns = pattern_names(load_templates())
    counters = {"a": {"published": 5, "bogus": 1.5, "flag": True}}
    enriched = enrich(status, counters, {"a": 30.0}, patterns, {"a": {"k": 7.5}})
    assert enriched["components"]["a"] == {
        "service": "fusion",
        "counters": {"published": 5},  # only integers from the network
        "pattern": "MultiTrackerFusion",
        "rate_hz": 30.0,
        "latency_ms": {"k": 7.5},
    }
    assert enriched["components"]["b"] == "odd"
    assert enriched["components"]["c"]["pattern"] is None
    assert status["components"]["a"] == {"service": "fusion"}  # a copy
    assert enrich({"components": []}, {}, {}, {}) == {"components": []}


def test_output_rates_are_published_samples_per_second_of_workers_seen_twice():
    before = {"a": {"published": 10}, "b": {"published": 3}, "c": {"published": "x"}}
    after = {"a": {"published": 40}, "b": {"published": 1}, "c": {"published": 9}, "d": {}}
    assert output_rates(before, after, 2.0) == {"a": 15.0, "b": 0.0}


def test_watched_relations_are_relation_keys_of_this_root_only():
    status = {
        "relations": {
            "C->A:6D": {"key": "ubitrack/demo/relation/C/A/6D/dynamic"},
            "C->HT:6D/static": {"key": "ubitrack/demo/relation/C/HT/6D/static"},
            "elsewhere": {"key": "ubitrack/other/relation/C/A/6D/dynamic"},
            "wild": {"key": "ubitrack/demo/relation/**/6D/dynamic"},
            "kind": {"key": "ubitrack/demo/relation/C/A/6D/sometimes"},
            "odd": {"key": 5},
            "odder": "x",
        }
    }
    assert watched_relations(status, KEYS) == {
        "C->A:6D": RelationId("C", "A", "6D"),
        "C->HT:6D/static": RelationId("C", "HT", "6D", static=True),
    }
    assert watched_relations({"relations": [1]}, KEYS) == {}
    many = {
        str(i): {"key": f"ubitrack/demo/relation/F{i}/A/6D/dynamic"}
        for i in range(MAX_RELATIONS + 10)
    }
    assert len(watched_relations({"relations": many}, KEYS)) == MAX_RELATIONS


JSON = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=4),
    lambda inner: (
        st.lists(inner, max_size=3)
        | st.dictionaries(st.sampled_from(FIELDS) | st.text(max_size=3), inner, max_size=4)
    ),
    max_leaves=25,
)


@settings(max_examples=300)
@given(st.dictionaries(st.sampled_from(FIELDS), JSON, max_size=8))
def test_any_status_gets_an_answer_on_every_path(status):
    for path in PATHS:
        reply = pages(Snapshot(4, enrich(status, {}, {}, {}))).respond("GET", path, "")
        assert reply.status in ((200, 404, 503) if path == "/frames.json" else (200, 502)), path
        if reply.content_type == "application/json":
            json.loads(reply.body)
    watched_relations(status, KEYS)
    json.dumps(relation_rows(status, {}))


def test_a_row_per_queried_relation_named_as_the_status_names_it():
    """The status names queries, relations and unsolved ones alike (``C->HT:6D/static``);
    the rows and the series use that name."""
    status = {
        "queries": {"C->A:6D": ["app", 5], "C->HT:6D/static": ["calibrate"], "X->Y:6D": "odd"},
        "application_hosts": {"C->A:6D": ["hmd"]},
        "unsolved": {"C->HT:6D/static": "no provider announces frame(s) HT"},
        "relations": {"C->A:6D": {"key": "ubitrack/demo/relation/C/A/6D/dynamic"}},
    }
    series = {"C->A:6D": {"rate_hz": [30.0]}, "gone->away:6D": {"rate_hz": [0.0]}}
    assert relation_rows(status, series) == {
        "C->A:6D": {
            "applications": ["app"],
            "hosts": ["hmd"],
            "unsolved": None,
            "series": {"rate_hz": [30.0]},
        },
        "C->HT:6D/static": {
            "applications": ["calibrate"],
            "hosts": [],
            "unsolved": "no provider announces frame(s) HT",
            "series": None,
        },
        "X->Y:6D": {"applications": [], "hosts": [], "unsolved": None, "series": None},
        "gone->away:6D": {
            "applications": [],
            "hosts": [],
            "unsolved": None,
            "series": {"rate_hz": [0.0]},
        },
    }
    assert list(relation_rows({"queries": [1], "unsolved": 3}, {})) == []


def test_flow_json_is_the_graph_the_page_lays_out_or_why_there_is_none():
    status = flow_status()
    for component in status["components"].values():
        component["container"] = "room-0"
    reply = pages(Snapshot(2, status, rates={"inversion-1": 59.6})).respond("GET", "/flow.json", "")
    graph = json.loads(reply.body)
    assert graph["groups"] == [{"id": "room-0", "lines": ["container room-0", "on room"]}]
    grouped = {node["id"] for node in graph["nodes"] if node["group"] == "room-0"}
    assert grouped == {"inversion-1", "fusion-2"}
    assert {"from": "inversion-1", "to": "fusion-2", "label": "6D, 60 Hz", "static": False} in (
        graph["wires"]
    )
    reply = pages(NO_AGENT).respond("GET", "/flow.json", "")
    assert reply.status == 503 and "no agent answers" in json.loads(reply.body)["error"]


def test_frames_json_places_relative_to_the_root_asked_for_or_the_trackers_frame():
    view = pages(running())
    default = json.loads(view.respond("GET", "/frames.json", "").body)
    assert (default["root"], default["default_root"], default["known"]) == (
        "ART",
        "ART",
        ["ART", "HT"],
    )
    assert default["frames"]["ART"]["position"] == [0.0, 0.0, 0.0]
    assert "HT" in default["unplaced"]  # the status's SRG, no samples yet
    assert pages(NO_AGENT).respond("GET", "/frames.json", "").status == 503
    chosen = json.loads(view.respond("GET", "/frames.json", "root=HT").body)
    assert chosen["root"] == "HT" and list(chosen["frames"]) == ["HT"]
