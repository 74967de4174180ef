"""What one answer of the 3D view's ``/frames.json`` costs, by the number of frames
(``commands.view.frame_watch.frames_from``: decode the latest sample of every followed
relation, place every frame, O((frames + relations) log relations); then the JSON the page
receives). The page asks once per animation frame (60 Hz on most displays), one request at a
time, so an answer well under 16 ms keeps it at display rate.

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

import json
import statistics
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from bench.report import run_sizes
from ubitrack_agent.commands.view.frame_watch import frames_from
from ubitrack_agent.core.codec import encode
from ubitrack_agent.core.measurements import ErrorPose, Position3D

RESULTS = Path(__file__).with_name("results") / "view_frames.json"


def random_tree(n: int, seed: int = 11) -> tuple[list[dict[str, Any]], dict, dict]:
    """A status's ``srg``, the keys followed and their latest payloads for a tree of ``n``
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
        wanted[key] = (parent, f"F{i}", bool(rng.random() < 0.5), f"p/e{i}")
        latest[key] = encode(sample)
    return srg, wanted, latest


def measure(n: int, repeat: int) -> dict[str, Any]:
    srg, wanted, latest = random_tree(n)
    times = []
    for _ in range(repeat):
        started = time.process_time()
        answer = json.dumps(frames_from(srg, wanted, latest, "F0", Counter()))
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


def main(argv: list[str] | None = None) -> int:
    description = __doc__.split("\n\n")[0]
    return run_sizes(description, "frames", [11, 30, 100, 256], 15, RESULTS, measure, argv)


if __name__ == "__main__":
    raise SystemExit(main())
