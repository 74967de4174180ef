"""What one answer of the 3D view's ``/frames.json`` costs, by the number of frames
(``commands.view.frame_watch.take`` and ``frames_from``: decode the sample that came since the
last answer on every followed relation, evaluate every relation at one display time
(``commands.view.align``: interpolated from its recent samples), place every frame, O((frames +
relations) log relations); then the JSON the page receives). The page asks once per animation
frame (60 Hz on most displays), one request at a time, so an answer well under 16 ms keeps it
at display rate.

The SRGs are random trees of ``n`` frames: each frame's 6D pose (with a covariance, as a
fusion's) in an earlier posed frame, measured or derived at random, a quarter of the frames
held by a 3D position instead (leaves); the root is the tree's first frame, so every frame is
placed. For each size, the median of ``--repeat`` timed answers (CPU time of this process,
``time.process_time``: the machine is shared) and the time per frame: flat if the growth is
linear. Run::

    .venv/bin/python -m bench.view_frames_bench       # writes bench/results/view_frames.json
    .venv/bin/python -m bench.view_frames_bench --frames 10 100

Measured side by side (2026-11-27, this machine, 2 cores shared, load about 5): one
eigendecomposition per frame with its axes turned into a quaternion (scipy) took 1.75, 4.46,
15.2 and 42.1 ms for 11, 30, 100 and 256 frames; one stacked eigendecomposition for all
frames, sending the axes as they are, 0.88, 2.10, 7.26 and 17.5 ms (70 to 80 us per frame).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import itertools
import json
import os
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from bench.calibrated_tracking_bench import scenario_with_true_calibration
from bench.report import run_sizes, write_results
from ubitrack_agent.commands.demo import dtrack_flags, simulator_arguments
from ubitrack_agent.commands.view.align import Recent
from ubitrack_agent.commands.view.frame_watch import frames_from, take
from ubitrack_agent.core.codec import encode
from ubitrack_agent.core.measurements import ErrorPose, Position3D
from ubitrack_agent.net import config
from ubitrack_agent.sim_trackers.scenario import load_scenario

RESULTS = Path(__file__).with_name("results") / "view_frames.json"
REDRAW = Path(__file__).with_name("results") / "view_redraw.json"


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def random_tree(n: int, seed: int = 11) -> tuple[list[dict[str, Any]], dict, dict]:
    """A status's ``srg``, the keys followed and a sample of each for a tree of ``n``
    frames (``F0`` the root)."""
    rng = np.random.default_rng(seed)
    srg, wanted, latest = [], {}, {}
    posed = ["F0"]  # frames with an orientation: a position holds no frame below it
    for i in range(1, n):
        parent = posed[int(rng.integers(0, len(posed)))]
        key = f"ubitrack/bench/data/p/e{i}"
        if rng.random() < 0.25:
            sample = Position3D(1, rng.normal(size=3), np.eye(3) * 1e-6)
            kind = "3D"
        else:
            a = rng.normal(size=(6, 6)) * 1e-3
            rotation = Rotation.from_rotvec(rng.normal(size=3)).as_quat()
            sample = ErrorPose(1, rotation, rng.normal(size=3), a @ a.T)
            kind = "6D"
            posed.append(f"F{i}")
        srg.append({"id": f"p/e{i}", "from": parent, "to": f"F{i}", "type": kind, "static": False})
        wanted[key] = (parent, f"F{i}", bool(rng.random() < 0.5), f"p/e{i}", False)
        latest[key] = sample
    return srg, wanted, latest


PERIOD_NS = 16_666_667
"""The relations' samples come at 60 Hz, one per relation between two answers."""


def measure(n: int, repeat: int) -> dict[str, Any]:
    srg, wanted, samples = random_tree(n)
    recent: dict[str, Recent] = {}
    counters: Counter[str] = Counter()

    def payloads(step: int) -> dict[str, list[bytes]]:
        stamp = (step + 1) * PERIOD_NS
        return {key: [encode(sample.restamped(stamp))] for key, sample in samples.items()}

    for step in range(64):  # the recent samples an answer interpolates in
        take(recent, wanted, payloads(step), counters)
    times = []
    for step in range(64, 64 + repeat):
        arrived = payloads(step)
        started = time.process_time()
        take(recent, wanted, arrived, counters)
        answer = json.dumps(frames_from(srg, wanted, recent, "F0"))
        times.append(time.process_time() - started)
    placed = len(json.loads(answer)["frames"])
    median = statistics.median(times)
    row = {
        "frames": n,
        "placed": placed,
        "answer_bytes": len(answer),
        "median_ms": round(1e3 * median, 3),
        "us_per_frame": round(1e6 * median / n, 1),
    }
    print(
        f"{n:4d} frames ({placed} placed, {len(answer) / 1e3:.1f} kB): "
        f"{row['median_ms']:7.2f} ms per answer ({row['us_per_frame']:.0f} us per frame)",
        flush=True,
    )
    return row


def start_figure1(directory: Path, web: int) -> tuple[list[subprocess.Popen], str]:
    """The figure-1 stack (agent, database serving the true C->HT, simulated camera and A.R.T.
    with its DTrack adapter), an application asking for C->A and ``ubitrack view`` on port
    ``web``, each in its own process group; the processes and the stack's domain."""
    port, art_port = free_port(), free_port()
    hub = config.Settings(listen=(f"tcp/127.0.0.1:{port}",), domain=f"redraw{port}")
    member = config.member_flags(hub)
    scenario_flag = ["--scenario", str(scenario_with_true_calibration(directory))]
    scenario = load_scenario(scenario_flag[1])
    simulators = simulator_arguments(scenario_flag, art_port, seed=7)
    commands = [
        ["agent", *config.as_flags(hub)],
        ["view", "--port", str(web), *member],
        ["sim", "database", *scenario_flag, *member],
        [*simulators["sim camera"], *member],
        simulators["sim art"],
        ["dtrack", "--quiet", *dtrack_flags(scenario.art, art_port), *member],
        ["subscribe", "C", "A", "--wait", "--timeout", "86400", *member],
    ]
    started = []
    for command in commands:
        started.append(
            subprocess.Popen(
                [sys.executable, "-m", "ubitrack_agent.cli", *command],
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                start_new_session=True,
            )
        )
    return started, hub.domain


def stop(processes: list[subprocess.Popen], domain: str) -> None:
    """End ``processes``' groups, then the agent's workers (their command lines name
    ``domain``)."""
    for process in processes:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGTERM)
    for process in processes:
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
    found = subprocess.run(["pgrep", "-f", domain], capture_output=True, text=True).stdout
    for pid in found.split():
        with contextlib.suppress(ProcessLookupError):
            os.kill(int(pid), signal.SIGKILL)


def read_json(url: str) -> Any:
    """The JSON a GET of ``url`` answers, None when it does not answer 200."""
    try:
        with urllib.request.urlopen(url, timeout=5) as response:
            return json.loads(response.read())
    except (OSError, ValueError):
        return None


def fused_rate(url: str) -> float | None:
    """The latest rate (Hz) the view measured for C->A, None before it flows."""
    row = ((read_json(url + "series.json") or {}).get("relations") or {}).get("C->A:6D")
    rates = row["series"]["rate_hz"] if row and row["series"] else []
    return rates[-1] if rates and rates[-1] else None


def wait_for(condition: Any, timeout: float, what: str) -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if found := condition():
            return found
        time.sleep(0.5)
    raise RuntimeError(f"not within {timeout} s: {what}")


COUNTERS = (
    "(() => { const f = document.getElementById('rate'); return [performance.now(),"
    " Number(f.dataset.drawn || 0), Number(f.dataset.placements || 0)]; })()"
)
"""The page's clock (ms) and its totals since it loaded: pictures drawn, placements at a new
display time (view3d.js writes them on the footer every 0.5 s)."""


ANIMATION_FRAMES = (
    "new Promise((done) => { let n = 0; const t0 = performance.now();"
    " const tick = () => { n += 1; if (performance.now() - t0 < 3000) requestAnimationFrame(tick);"
    " else done(1e3 * n / (performance.now() - t0)); }; requestAnimationFrame(tick); })"
)
"""Animation frames per second the browser gives the page, counted over 3 s: the most the
page can draw at (it draws once per animation frame)."""


async def page_counters(debugging: int, seconds: float) -> tuple[list[list[float]], float]:
    """The 3D page's :data:`COUNTERS` once a second for ``seconds``, read over the Chrome
    DevTools Protocol (``Runtime.evaluate``) from the browser listening on ``debugging``,
    then :data:`ANIMATION_FRAMES`."""
    import aiohttp

    async with aiohttp.ClientSession() as http:
        async with http.get(f"http://127.0.0.1:{debugging}/json/list") as listing:
            targets = await listing.json()
        (page,) = [t for t in targets if t["type"] == "page" and t["url"].endswith("/3d")]
        async with http.ws_connect(page["webSocketDebuggerUrl"], max_msg_size=0) as ws:

            async def evaluate(number: int, expression: str) -> Any:
                params = {"expression": expression, "returnByValue": True, "awaitPromise": True}
                await ws.send_json({"id": number, "method": "Runtime.evaluate", "params": params})
                answer = await ws.receive_json()
                while answer.get("id") != number:  # events, if any, are skipped
                    answer = await ws.receive_json()
                return answer["result"]["result"]["value"]

            readings = []
            for number in range(int(seconds) + 1):
                readings.append(await evaluate(number, COUNTERS))
                await asyncio.sleep(1.0)
            animation = await evaluate(-1, ANIMATION_FRAMES)
    return readings, animation


def measure_redraw(seconds: float, warm_up: float, window: str) -> dict[str, Any]:
    """Pictures drawn and new placements per second in headless Chromium (software WebGL)
    showing the 3D view of the running figure-1 stack, over ``seconds`` after ``warm_up``;
    beside the rates of the relations it draws (the view's /status.json and /series.json)."""
    binary = next(filter(None, map(shutil.which, ("chromium", "chromium-browser"))), None)
    if binary is None:
        raise SystemExit("needs chromium (apt-get install chromium)")
    with tempfile.TemporaryDirectory() as directory:
        web = free_port()
        url = f"http://127.0.0.1:{web}/"
        processes, domain = start_figure1(Path(directory), web)
        try:
            wait_for(lambda: fused_rate(url), 120, "C->A flows")
            profile = Path(directory) / "profile"
            browser = subprocess.Popen(
                [
                    binary,
                    "--headless",
                    "--no-sandbox",
                    "--use-angle=swiftshader",
                    "--enable-unsafe-swiftshader",
                    "--no-first-run",
                    "--remote-debugging-port=0",
                    f"--user-data-dir={profile}",
                    f"--window-size={window}",
                    url + "3d",
                ],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
                start_new_session=True,
            )
            processes.append(browser)
            active = profile / "DevToolsActivePort"
            wait_for(lambda: active.exists() and active.read_text().strip(), 30, "DevTools")
            debugging = int(active.read_text().split()[0])
            time.sleep(warm_up)
            readings, animation = asyncio.run(page_counters(debugging, seconds))
            series = read_json(url + "series.json")["relations"]["C->A:6D"]["series"]
            frames = read_json(url + "frames.json")
        finally:
            stop(processes, domain)
    spans = list(itertools.pairwise(readings))
    drawn = [1e3 * (b[1] - a[1]) / (b[0] - a[0]) for a, b in spans]
    placed = [1e3 * (b[2] - a[2]) / (b[0] - a[0]) for a, b in spans]
    result = {
        "seconds": seconds,
        "window": window,
        "pictures_per_s_median": round(statistics.median(drawn), 1),
        "pictures_per_s_range": [round(min(drawn), 1), round(max(drawn), 1)],
        "placements_per_s_median": round(statistics.median(placed), 1),
        "animation_frames_per_s": round(animation, 1),
        "c_to_a_rate_hz": round(statistics.median(series["rate_hz"][-int(seconds) :]), 1),
        "frames_placed": len(frames["frames"]),
        "behind_ms_last": frames["behind_ms"],
        "load_average": os.getloadavg()[0],
    }
    print(
        f"3D view in headless Chromium (software WebGL, {window}), "
        f"{len(frames['frames'])} frames, "
        f"C->A at {result['c_to_a_rate_hz']} Hz: {result['pictures_per_s_median']} pictures/s "
        f"drawn (median of {len(drawn)} s; {result['pictures_per_s_range']}), "
        f"{result['placements_per_s_median']} new placements/s; the browser gives "
        f"{result['animation_frames_per_s']} animation frames/s",
        flush=True,
    )
    return result


def main(argv: list[str] | None = None) -> int:
    description = __doc__.split("\n\n")[0]
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--browser", type=float, metavar="SECONDS")
    parser.add_argument("--warm-up", type=float, default=10.0)
    parser.add_argument("--window", default="1280,1100", help="the browser's window size")
    known, rest = parser.parse_known_args(argv)
    if known.browser is None:
        return run_sizes(description, "frames", [11, 30, 100, 256], 15, RESULTS, measure, rest)
    write_results(REDRAW, measure_redraw(known.browser, known.warm_up, known.window))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
