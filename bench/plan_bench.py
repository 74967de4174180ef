"""Planning time: the paper's setup and generated SRGs of 10, 100 and 1,000 frames.

Run as ``python -m bench.plan_bench``; prints a table and writes ``bench/results/plan.json``.

Generated SRGs model a building: rooms of 10 frames hang off a building frame ``B`` by static
database edges. A *camera room* holds a world frame ``W``, a tracker ``T`` (static in ``W``)
tracking a head target ``H``, a camera ``C`` rigid on ``H`` with image plane ``I``, and a marker
``M`` (static in ``W``) with four features ``F1..F4`` seen by the camera: the loop of figure 1.
A *6D room* has ``W``, two trackers ``T`` (tracking ``H1..H3``) and ``U`` (tracking ``H1``), a
camera ``C`` rigid on ``H1`` and objects ``O1..O3`` static in ``W``, only 6D edges. For each size
the benchmark times

* a first plan of a query inside one room (``C -> M`` / ``C -> O1``) and across the building
  (first room's camera to the last room's marker/object),
* a replan of the in-room query after its tracker disappears, and after it reappears,

and, on the 6D-only graphs, pytransform3d's ``TransformManager`` in the same run: add every edge
(with a random transform; it recomputes all shortest paths on each addition), then
``get_transform`` for the same query. Ratios are planner time over TransformManager time, for
the query alone and for adding the edges plus the query. Figures are medians over repeats.
"""

from __future__ import annotations

import json
import platform
import statistics
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import networkx as nx
import numpy as np

from ubitrack_agent.graph.planner import Query, plan
from ubitrack_agent.graph.srg import add_measured_edge, load_setup, new_srg, remove_provider
from ubitrack_agent.graph.templates import Template, load_templates

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results" / "plan.json"
SIZES = (10, 100, 1000)


def camera_building(frames: int) -> nx.MultiDiGraph:
    """An SRG of ``frames // 10`` camera rooms (10 frames each) plus the building frame."""
    srg = new_srg()
    for r in range(max(1, frames // 10)):
        w, t, h, c, i, m = (f"{x}{r}" for x in ("W", "T", "H", "C", "I", "M"))
        add_measured_edge(srg, "B", w, "6D", static=True)
        add_measured_edge(srg, w, t, "6D", static=True)
        add_measured_edge(srg, t, h, "6D", provider=t)
        add_measured_edge(srg, c, h, "6D", static=True)
        add_measured_edge(srg, c, i, "3x4", static=True)
        add_measured_edge(srg, w, m, "6D", static=True)
        for k in range(1, 5):
            add_measured_edge(srg, i, f"F{k}_{r}", "2D", provider=c)
            add_measured_edge(srg, m, f"F{k}_{r}", "3D", static=True)
    return srg


def pose_building(frames: int) -> nx.MultiDiGraph:
    """A 6D-only SRG of ``frames // 10`` rooms (10 frames each) plus the building frame."""
    srg = new_srg()
    for r in range(max(1, frames // 10)):
        w, t, u, c = f"W{r}", f"T{r}", f"U{r}", f"C{r}"
        add_measured_edge(srg, "B", w, "6D", static=True)
        add_measured_edge(srg, w, t, "6D", static=True)
        add_measured_edge(srg, w, u, "6D", static=True)
        for k in range(1, 4):
            add_measured_edge(srg, t, f"H{k}_{r}", "6D", provider=t)
        add_measured_edge(srg, u, f"H1_{r}", "6D", provider=u)
        add_measured_edge(srg, c, f"H1_{r}", "6D", static=True)
        for k in range(1, 4):
            add_measured_edge(srg, w, f"O{k}_{r}", "6D", static=True)
    return srg


def median_ms(fn: Callable[[], object], repeats: int) -> float:
    """Median wall time of ``fn()`` in milliseconds over ``repeats`` runs (after one warm-up)."""
    fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1e3


def random_pose(rng: np.random.Generator) -> np.ndarray:
    """A random 4x4 rigid transform."""
    from pytransform3d.transformations import transform_from
    from scipy.spatial.transform import Rotation

    return transform_from(Rotation.random(random_state=rng).as_matrix(), rng.normal(size=3))


def transform_manager(srg: nx.MultiDiGraph, repeats: int) -> tuple[object, float]:
    """pytransform3d: a TransformManager holding every 6D edge of ``srg`` (random poses), and
    the median time (ms) to build it by adding the edges one by one."""
    from pytransform3d.transform_manager import TransformManager

    rng = np.random.default_rng(0)
    poses = [(u, v, random_pose(rng)) for u, v in srg.edges()]
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        tm = TransformManager(check=False)
        for u, v, pose in poses:
            # the edge u->v is the pose of v in u: it maps v coordinates to u ("v2u")
            tm.add_transform(v, u, pose)
        times.append(time.perf_counter() - start)
    return tm, statistics.median(times) * 1e3


def plan_figures(
    srg: nx.MultiDiGraph, templates: Sequence[Template], query: Query, tracker: str, repeats: int
) -> dict:
    """First plan, replan after ``tracker`` disappears and after it reappears."""
    without = remove_provider(srg, tracker)
    first = median_ms(lambda: plan(srg, templates, query), repeats)
    gone = median_ms(lambda: plan(without, templates, query), repeats)
    back = median_ms(lambda: plan(srg, templates, query), repeats)
    best = plan(srg, templates, query)[0]
    return {
        "first_plan_ms": round(first, 3),
        "replan_sensor_gone_ms": round(gone, 3),
        "replan_sensor_back_ms": round(back, 3),
        "best_steps": [s.template.pattern for s in best.steps],
    }


def main() -> None:
    templates = load_templates()
    results: dict = {
        "date": time.strftime("%Y-%m-%d"),
        "python": platform.python_version(),
        "machine": platform.machine(),
        "paper": {},
        "camera_building": {},
        "pose_building": {},
    }
    tracking = load_setup(ROOT / "examples" / "paper_tracking.yaml")
    calibration = load_setup(ROOT / "examples" / "paper_calibration.yaml")
    for name, srg, query in (
        ("tracking C->A 6D", tracking, Query("C", "A", "6D")),
        ("calibration C->HT 6D static", calibration, Query("C", "HT", "6D", True)),
    ):
        results["paper"][name] = round(
            median_ms(lambda s=srg, q=query: plan(s, templates, q), 20), 3
        )
    results["paper"]["tracking, ART gone"] = round(
        median_ms(
            lambda: plan(remove_provider(tracking, "ART"), templates, Query("C", "A", "6D")), 20
        ),
        3,
    )
    for frames in SIZES:
        repeats = 20 if frames < 1000 else 7
        rooms = max(1, frames // 10)
        srg = camera_building(frames)
        mid = rooms // 2
        results["camera_building"][frames] = {
            "frames": srg.number_of_nodes(),
            "edges": srg.number_of_edges(),
            "in_room": plan_figures(
                srg, templates, Query(f"C{mid}", f"M{mid}", "6D"), f"T{mid}", repeats
            ),
            "across": round(
                median_ms(
                    lambda s=srg, r=rooms: plan(s, templates, Query("C0", f"M{r - 1}", "6D")),
                    repeats,
                ),
                3,
            ),
        }
        srg = pose_building(frames)
        in_room = Query(f"C{mid}", f"O1_{mid}", "6D")
        across = Query("C0", f"O1_{rooms - 1}", "6D")
        entry: dict = {"frames": srg.number_of_nodes(), "edges": srg.number_of_edges()}
        entry["in_room"] = plan_figures(srg, templates, in_room, f"T{mid}", repeats)
        tm, build_ms = transform_manager(srg, 1 if frames >= 1000 else 5)
        entry["transform_manager_build_ms"] = round(build_ms, 3)
        for label, query in (("in_room", in_room), ("across", across)):
            ours = median_ms(lambda s=srg, q=query: plan(s, templates, q), repeats)
            get_ms = median_ms(lambda q=query, t=tm: t.get_transform(q.target, q.source), 50)
            entry[f"{label}_vs_transform_manager"] = {
                "planner_ms": round(ours, 3),
                "transform_manager_get_ms": round(get_ms, 4),
                "transform_manager_add_and_get_ms": round(build_ms + get_ms, 3),
                "ratio_to_get": round(ours / get_ms, 1),
                "ratio_to_add_and_get": round(ours / (build_ms + get_ms), 3),
            }
        results["pose_building"][frames] = entry
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")
    print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
