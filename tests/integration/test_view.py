"""``ubitrack view`` live, seen in headless Chromium (issue 14, item 3; issue 31, item 3).

The view starts first, with no agent: its page says so. Then the figure-1 stack joins (agent,
database serving the true C->HT, simulated camera, simulated A.R.T. with its DTrack adapter, the
simulated world's ground truth) with an application asking for C->A, and a second view whose
PATH holds no Graphviz. Chromium loads both views' pages: the data flow drawn in the browser
(components by pattern, inside their container's box, a legend), C->A with its rate, latency
and error sparklines (axes, units, current value), and the 3D view of the frames (every frame
of the SRG placed, relative to the tracker's frame and to a root chosen in the address). The
frames' placement is checked against the simulated world's ground truth. Screenshots are kept
in ``test-artifacts/`` (the paths are printed). Skipped, saying how to install it, where no
Chromium is found (``.ci/run`` installs it); the view with Graphviz only where ``dot`` is.
"""

from __future__ import annotations

import html
import json
import math
import os
import re
import shutil
import socket
import subprocess
import sys
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

import pytest

from bench.calibrated_tracking_bench import scenario_with_true_calibration
from tests.integration.conftest import kill_tagged
from tests.integration.zenoh_helpers import free_port, wait_until
from ubitrack_agent.commands.demo import dtrack_flags, simulator_arguments
from ubitrack_agent.core.codec import decode
from ubitrack_agent.io.application import Relation
from ubitrack_agent.net import config
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.session import open_session
from ubitrack_agent.net.time_queries import fetch_at
from ubitrack_agent.sim_trackers.scenario import load_scenario

pytestmark = pytest.mark.integration

ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts"
"""Where the screenshot is kept (git-ignored)."""

PATTERNS = ("PoseEstimation2D3D", "MultiTrackerFusion", "Inversion", "Concatenation")
"""Patterns of the fused C->A flow's components (the paper's figure 6: each step a component,
one box each)."""

WEBGL = ("--use-angle=swiftshader", "--enable-unsafe-swiftshader")
"""Chromium's software WebGL, for the 3D view in a headless browser without a GPU."""


def chromium() -> str:
    """The Chromium binary, or skip saying how to install it."""
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if found := shutil.which(name):
            return found
    pytest.skip("chromium not installed: apt-get install chromium")


def browse(processes: list, binary: str, url: str, profile: Path, *action: str) -> str:
    """Chromium's output of ``action`` on ``url`` once the page's script has run for 5 s of
    virtual time (fetches pause it, so the page has redrawn several times)."""
    command = [
        binary,
        "--headless",
        "--no-sandbox",  # CI runs as root
        *WEBGL,
        "--no-first-run",
        "--disable-extensions",
        "--disable-background-networking",
        f"--user-data-dir={profile}",
        "--virtual-time-budget=5000",
        *action,
        url,
    ]
    browser = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    processes.append(browser)
    out, err = browser.communicate(timeout=120)
    assert browser.returncode == 0, err[-3000:]
    return out


def get(url: str) -> tuple[int, bytes]:
    """Status and body of a GET."""
    try:
        with urllib.request.urlopen(url, timeout=10) as response:
            return response.status, response.read()
    except urllib.error.HTTPError as error:
        return error.code, error.read()


def answers(url: str) -> bool:
    try:
        return get(url)[0] == 200
    except OSError:  # not listening yet
        return False


def read_json(url: str) -> Any:
    return json.loads(get(url)[1])


def without_graphviz(tmp_path: Path) -> dict[str, str]:
    """An environment whose PATH finds no program at all, Graphviz's ``dot`` included (the
    view runs as ``sys.executable`` and needs none)."""
    empty = tmp_path / "no-graphviz-bin"
    empty.mkdir()
    return {**os.environ, "PATH": str(empty)}


def test_the_view_shows_the_running_flow_in_headless_chromium(processes, tmp_path, capsys):
    binary = chromium()
    graphviz = shutil.which("dot") is not None
    port, art_port, web, web_dot = free_port(), free_port(), free_port(), free_port()
    domain = f"view{port}"
    hub = config.Settings(listen=(f"tcp/127.0.0.1:{port}",), domain=domain)
    member = config.member_flags(hub)
    scenario_path = scenario_with_true_calibration(tmp_path)
    scenario = load_scenario(str(scenario_path))
    scenario_flag = ["--scenario", str(scenario_path)]
    simulators = simulator_arguments(scenario_flag, art_port, seed=7)
    url = f"http://127.0.0.1:{web}/"

    def start(*arguments: str, env: dict[str, str] | None = None) -> None:
        command = [sys.executable, "-m", "ubitrack_agent.cli", *arguments]
        processes.append(
            subprocess.Popen(command, stdin=subprocess.DEVNULL, start_new_session=True, env=env)
        )

    start("view", "--port", str(web), *member, env=without_graphviz(tmp_path))
    wait_until(lambda: answers(url + "series.json"), timeout=30, interval=0.1)
    code, body = get(url + "status.json")
    assert code == 503 and "no agent answers" in json.loads(body)["error"]
    assert get(url + "nowhere")[0] == 404 and get(url + "?t=1")[0] == 400
    with socket.create_connection(("127.0.0.1", web), timeout=10) as raw:
        raw.sendall(b"\x16\x03\x01 no HTTP at all\r\n\r\n")  # a TLS hello, say
        assert re.match(rb"HTTP/1\.[01] 400 ", raw.recv(64))
    alone = html.unescape(browse(processes, binary, url, tmp_path / "profile", "--dump-dom"))
    assert re.search(r'<p id="problem" class="problem">no agent answers on [^<]*</p>', alone)
    views = {"without Graphviz": url}
    if graphviz:
        start("view", "--port", str(web_dot), *member)
        views["with Graphviz"] = f"http://127.0.0.1:{web_dot}/"
        wait_until(lambda: answers(views["with Graphviz"] + "series.json"), timeout=30)

    start("agent", *config.as_flags(hub))
    keys = KeySpace(hub.key_prefix)
    with (
        open_session(config.member_of(hub)) as session,
        Relation(
            session, keys, RelationId("C", "A", "6D"), keep_waiting=True
        ) as relation,  # asked before the sensors start
    ):
        start("sim", "database", *scenario_flag, *member)
        start("sim", "world", "--quiet", *scenario_flag, *member)
        start(*simulators["sim camera"], *member)
        start(*simulators["sim art"])
        start("dtrack", "--quiet", *dtrack_flags(scenario.art, art_port), *member)
        relation.wait_for(timeout=90)
        for view in views.values():
            wait_until(lambda view=view: fused_and_measured(view), timeout=90, interval=0.5)
            # Wires into components carry the latency their worker measures (figure 6's labels).
            wait_until(
                lambda view=view: re.search(
                    rb'label="6D, \d+ Hz, \d+ ms"', get(view + "flow.dot")[1]
                )
            )
            wait_until(
                lambda view=view: "C" in read_json(view + "frames.json")["frames"], timeout=30
            )
        distance = assert_frames_match_the_truth(session, keys, url)
        missing = get(url + "flow.svg")
        assert missing[0] == 503 and b"Graphviz's dot is not installed" in missing[1]
        if graphviz:
            drawn = get(views["with Graphviz"] + "flow.svg")
            assert drawn[0] == 200 and drawn[1].lstrip().startswith((b"<?xml", b"<svg"))
        ARTIFACTS.mkdir(exist_ok=True)
        shots = []

        def seen(view: str, profile: Path, size: str, file: str) -> str:
            """The DOM of ``view`` in Chromium, which keeps a screenshot of it as ``file``
            (one launch for both)."""
            screenshot = ARTIFACTS / file
            screenshot.unlink(missing_ok=True)
            shot = (f"--screenshot={screenshot}", f"--window-size={size}")
            dom = browse(processes, binary, view, profile, "--dump-dom", *shot)
            assert screenshot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
            shots.append(screenshot)
            return html.unescape(dom)

        for name, view in views.items():
            suffix = "" if name == "without Graphviz" else "-with-graphviz"
            profile = tmp_path / f"profile{suffix}"
            dom = seen(view, profile, "1280,1500", f"live-view{suffix}.png")
            assert_the_flow_page_shows_the_running_flow(dom)
            assert_graphviz_is_an_option(
                html.unescape(
                    browse(processes, binary, view + "#engine=graphviz", profile, "--dump-dom")
                ),
                installed=name == "with Graphviz",
            )
            dom3d = seen(view + "3d", profile, "1280,1100", f"view-3d{suffix}.png")
            assert_the_3d_view_places_the_frames(dom3d, root="ART", default=True)
            chosen = html.unescape(
                browse(processes, binary, view + "3d#root=C", profile, "--dump-dom")
            )
            assert_the_3d_view_places_the_frames(chosen, root="C", default=False)
    with capsys.disabled():
        print(f"\nA placed relative to C {1e3 * distance:.1f} mm from the truth at display time")
        print("relations at the last placement:", read_json(url + "frames.json")["relations"])
        print("screenshots of the views:", *(str(shot) for shot in shots), sep="\n  ")
    kill_tagged(domain)


def fused_and_measured(view: str) -> bool:
    """The fused flow runs and ``view`` has measured C->A against the truth."""
    if get(view + "status.json")[0] != 200:
        return False
    components = read_json(view + "status.json")["components"].values()
    alive = {c["pattern"] for c in components if c["alive"]}
    row = read_json(view + "series.json")["relations"].get("C->A:6D")
    series = row and row["series"]
    return bool(
        set(PATTERNS) <= alive
        and all(c["alive"] for c in components)
        and series
        and series["error_mm"][-1:] not in ([], [None])
        and series["latency_ms"][-1:] not in ([], [None])
    )


def assert_frames_match_the_truth(session: Any, keys: KeySpace, url: str) -> float:
    """The view's placement of A relative to C is the simulated world's C->A at the
    placement's display time (every relation taken at that instant, :mod:`.align`), within
    15 mm (the fused C->A's error is a few mm: docs/performance.md); every frame of the SRG is
    placed but the image plane. Returns the distance (m)."""
    placed = read_json(url + "frames.json?root=C")
    assert placed["display_time_ns"] and placed["behind_ms"] >= 0, placed
    assert {r["mode"] for r in placed["relations"].values()} <= {"interpolated", "static"}
    truth = decode(fetch_at(session, keys.truth("C", "A"), placed["display_time_ns"], timeout=2.0))
    distance = math.dist(placed["frames"]["A"]["position"], truth.translation)
    assert distance < 0.015, (placed["frames"]["A"], truth)
    assert set(placed["known"]) - set(placed["frames"]) == {"IP"}, placed["unplaced"]
    assert "2D and 3x4" in placed["unplaced"]["IP"]
    assert placed["frames"]["C"]["position"] == [0.0, 0.0, 0.0]
    fused = [frame for frame in placed["frames"].values() if frame["ellipsoid"]]
    assert fused, placed  # covariances reach the placement
    return distance


def assert_the_flow_page_shows_the_running_flow(dom: str) -> None:
    assert re.search(r'<p id="agent">agent [0-9a-f]+\.\d+ \(active\) on ubitrack/view\d+', dom)
    components = re.search(r'<table id="components">(.*?)</table>', dom, re.DOTALL)
    assert components, dom[:3000]
    for pattern in PATTERNS:
        assert f"<td>{pattern}</td>" in components.group(1), components.group(1)
    row = re.search(r'<tr data-relation="C->A:6D">(.*?)</tr>', dom, re.DOTALL)
    assert row, dom[:3000]
    values = re.findall(r'<span class="value">([^<]*)</span>', row.group(1))
    assert len(values) == 3, row.group(1)
    rate, latency, error = (float(v.split()[0]) for v in values)
    assert [v.split()[1] for v in values] == ["Hz", "ms", "mm"]
    assert rate > 0 and latency > 0 and error >= 0
    assert row.group(1).count("<polyline") >= 3  # the three sparklines
    for unit in ("Hz", "ms", "mm"):  # each with its value axis, in its unit, and a time axis
        assert re.search(rf'<text [^>]*class="tick">\d+(\.\d+)? {unit}</text>', row.group(1)), unit
    assert row.group(1).count(">now</text>") == 3
    assert "no agent answers" not in dom
    # The flow drawn in the browser: a box per component, named by pattern, inside its
    # container's box; a legend; Graphviz's picture not shown, no problem reported.
    flow = re.search(r'<svg id="flow"[^>]*>(.*?)</svg>', dom, re.DOTALL)
    assert flow, dom[:3000]
    drawn = flow.group(1)
    boxes = re.findall(r'<g class="node component"[^>]*>(.*?)</g>', drawn, re.DOTALL)
    names = {re.search(r'class="name">([^<]*)<', box).group(1) for box in boxes}
    assert set(PATTERNS) <= names, names
    groups = re.findall(r'class="group-label">container ([^<,]*), on [^<]*</text>', drawn)
    assert groups, drawn[:2000]
    assert len(re.findall(r'<path class="wire', drawn)) >= 8
    assert re.search(r'class="wire-label">6D, \d+ Hz, \d+ ms</text>', drawn)
    assert re.search(r'<g class="node provider"[^>]*>.*?>ART</text>', drawn, re.DOTALL)
    assert re.search(r'<g class="node application"[^>]*>.*?>C->A:6D</text>', drawn, re.DOTALL)
    assert '<img id="flow-picture" alt="the live data flow, drawn by Graphviz" hidden=""' in dom
    assert '<p id="flow-problem" class="problem" hidden=""' in dom
    legend = re.search(r'<svg id="flow-legend"[^>]*>(.*?)</svg>', dom, re.DOTALL)
    assert legend and "container: components run in one process" in legend.group(1)


def assert_graphviz_is_an_option(dom: str, installed: bool) -> None:
    """With Graphviz chosen (``#engine=graphviz``): its picture where ``dot`` is installed;
    else the reason, and the flow drawn in the browser all the same."""
    picture = re.search(r'<img id="flow-picture"[^>]*>', dom).group(0)
    drawn = re.search(r'<svg id="flow"[^>]*>', dom).group(0)
    problem = re.search(r'<p id="flow-problem"[^>]*>([^<]*)</p>', dom)
    if installed:
        assert 'src="blob:' in picture and "hidden" not in picture, picture
        assert "hidden" in drawn and "hidden" in problem.group(0)
    else:
        assert "hidden" in picture and "hidden" not in drawn
        assert problem.group(1) == (
            "no picture: Graphviz's dot is not installed (Debian: apt install graphviz); "
            "drawn in the browser instead"
        )
        assert re.search(r'<g class="node component"', dom)


def assert_the_3d_view_places_the_frames(dom: str, root: str, default: bool) -> None:
    assert '<p id="problem" class="problem" hidden=""' in dom, dom[:3000]  # WebGL drew
    summary = re.search(r'<p id="agent">(\d+) of (\d+) frames placed relative to (\w+)', dom)
    assert summary, dom[:3000]
    assert (int(summary.group(1)), int(summary.group(2)), summary.group(3)) == (10, 11, root)
    assert ("(the tracker's frame)" in dom) == default
    rows = dict(re.findall(r'<tr[^>]* data-frame="(\w+)"><td>\w+</td><td>([^<]*)</td>', dom))
    assert set(rows) == {"ART", "WT", "HT", "C", "A", "IP", *(f"F{i}" for i in range(1, 6))}
    assert rows[root] == "0.000, 0.000, 0.000" and rows["IP"] == "not placed"
    placed = r'<span[^>]* style="left: [-\d.]+px; top: [-\d.]+px;"[^>]*>(\w+)</span>'
    labels = re.findall(placed, dom)
    assert set(labels) == set(rows) - {"IP"}, labels  # a name beside every placed frame
    assert re.search(r"relative to \w+[^<]*, at one instant \d+ ms before the newest sample", dom)
    # It keeps redrawing while samples arrive: pictures drawn, and placements at a new display
    # time, since the page loaded (how fast is bench/view_frames_bench.py --browser's business).
    footer = re.search(r'<footer id="rate" data-drawn="(\d+)" data-placements="(\d+)"', dom)
    assert footer, dom[-2000:]
    drawn, placements = int(footer.group(1)), int(footer.group(2))
    assert drawn >= placements >= 2, footer.group(0)
