"""``ubitrack view`` live, seen in headless Chromium (issue 14, item 3).

The view starts first, with no agent: its page says so. Then the figure-1 stack joins (agent,
database serving the true C->HT, simulated camera, simulated A.R.T. with its DTrack adapter, the
simulated world's ground truth) with an application asking for C->A; Chromium loads the page,
which must show the running flow's components by pattern and C->A with its rate, latency and
error. The screenshot is kept in ``test-artifacts/live-view.png`` (the path is printed).
Skipped, saying how to install it, where no Chromium is found (``.ci/run`` installs it).
"""

from __future__ import annotations

import html
import json
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
from ubitrack_agent.io.application import Relation
from ubitrack_agent.net import config
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.session import open_session
from ubitrack_agent.sim_trackers.scenario import load_scenario

pytestmark = pytest.mark.integration

ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts"
"""Where the screenshot is kept (git-ignored)."""

PATTERNS = ("PoseEstimation2D3D", "MultiTrackerFusion", "Inversion", "Concatenation")
"""Patterns of the fused C->A flow's components (the paper's figure 6: each step a component,
one box each)."""


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
        "--disable-gpu",
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


def test_the_view_shows_the_running_flow_in_headless_chromium(processes, tmp_path, capsys):
    binary = chromium()
    port, art_port, web = free_port(), free_port(), free_port()
    domain = f"view{port}"
    hub = config.Settings(listen=(f"tcp/127.0.0.1:{port}",), domain=domain)
    member = config.member_flags(hub)
    scenario_path = scenario_with_true_calibration(tmp_path)
    scenario = load_scenario(str(scenario_path))
    scenario_flag = ["--scenario", str(scenario_path)]
    simulators = simulator_arguments(scenario_flag, art_port, seed=7)
    url = f"http://127.0.0.1:{web}/"

    def start(*arguments: str) -> None:
        command = [sys.executable, "-m", "ubitrack_agent.cli", *arguments]
        processes.append(
            subprocess.Popen(command, stdin=subprocess.DEVNULL, start_new_session=True)
        )

    start("view", "--port", str(web), *member)
    wait_until(lambda: answers(url + "series.json"), timeout=30, interval=0.1)
    code, body = get(url + "status.json")
    assert code == 503 and "no agent answers" in json.loads(body)["error"]
    assert get(url + "nowhere")[0] == 404 and get(url + "?t=1")[0] == 400
    with socket.create_connection(("127.0.0.1", web), timeout=10) as raw:
        raw.sendall(b"\x16\x03\x01 no HTTP at all\r\n\r\n")  # a TLS hello, say
        assert re.match(rb"HTTP/1\.[01] 400 ", raw.recv(64))
    alone = html.unescape(browse(processes, binary, url, tmp_path / "profile", "--dump-dom"))
    assert re.search(r'<p id="problem" class="problem">no agent answers on [^<]*</p>', alone)

    start("agent", *config.as_flags(hub))
    with (
        open_session(config.member_of(hub)) as session,
        Relation(
            session, KeySpace(hub.key_prefix), RelationId("C", "A", "6D"), keep_waiting=True
        ) as relation,  # asked before the sensors start
    ):
        start("sim", "database", *scenario_flag, *member)
        start("sim", "world", "--quiet", *scenario_flag, *member)
        start(*simulators["sim camera"], *member)
        start(*simulators["sim art"])
        start("dtrack", "--quiet", *dtrack_flags(scenario.art, art_port), *member)
        relation.wait_for(timeout=90)

        def fused_and_measured() -> bool:
            """The fused flow runs and the view has measured C->A against the truth."""
            if get(url + "status.json")[0] != 200:
                return False
            components = read_json(url + "status.json")["components"].values()
            alive = {c["pattern"] for c in components if c["alive"]}
            row = read_json(url + "series.json")["relations"].get("C->A:6D")
            series = row and row["series"]
            return (
                set(PATTERNS) <= alive
                and all(c["alive"] for c in components)
                and series
                and series["error_mm"][-1:] not in ([], [None])
                and series["latency_ms"][-1:] not in ([], [None])
            )

        wait_until(fused_and_measured, timeout=90, interval=0.5)
        # Wires into components carry the latency their worker measures (figure 6's labels).
        wait_until(lambda: re.search(rb'label="6D, \d+ Hz, \d+ ms"', get(url + "flow.dot")[1]))
        dom = html.unescape(browse(processes, binary, url, tmp_path / "profile", "--dump-dom"))
        ARTIFACTS.mkdir(exist_ok=True)
        screenshot = ARTIFACTS / "live-view.png"
        screenshot.unlink(missing_ok=True)
        shot = (f"--screenshot={screenshot}", "--window-size=1280,900")
        browse(processes, binary, url, tmp_path / "profile", *shot)
    with capsys.disabled():
        print(f"\nscreenshot of the live view: {screenshot}")
    assert screenshot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

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
    assert "no agent answers" not in dom
    kill_tagged(domain)
