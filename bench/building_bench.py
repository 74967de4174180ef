"""Planning in a building (issue [scale], point 4): plan time against a plain shortest path.

Run as ``python -m bench.building_bench [--quick] [--limit S] [--repeats N] [--series NAME,...]
[--compare-with DIR] [--out FILE]``; prints a table and the growth of each series, and writes
``bench/results/building.json`` (or ``--out``). ``--compare-with DIR`` plans every row again,
right after, with the planner of the checkout in ``DIR`` (e.g. ``git worktree add /tmp/before
5e538ac``), so that both are measured side by side in one run.

Setups come from :mod:`bench.building` (rooms in a star or a corridor, K redundant trackers,
bodies, cameras on bodies seeing a marker target with 5 features, static surveys, shared
targets). The series, each a query on a growing setup:

* ``in_room``: camera -> marker in one room (``C0_1 -> M0``, 6D), K = 0, 2, 5, 7, 10, 15, 20,
  30, 50, 100, 200, 500 redundant trackers;
* ``in_room_large``: the same with K = 1,000, 2,000, 5,000 (ten times the largest
  ``in_room`` row: where the growth in K shows; about a minute);
* ``in_building``: the same query in one room of a 50-room star, K = 2, 4, 10, 20 (the region
  restriction should make it cost what a lone room costs);
* ``head_to_head_k1`` / ``_k2``: head -> head across two rooms (``H0_1 -> H1_1``), 1, 2, 3, 4,
  5, 6, 8, 10, 15, 20 bodies per room (and 30, 50, 100 with K = 2), each seen by K + 1 = 2 / 3
  trackers; the rooms are equipped alike, so one room's part serves both;
  ``head_to_head_k5`` / ``_k10``: the same with 6 / 11 trackers, 1, 2, 4, 8, 16, 32 bodies;
  ``head_to_head_k2_unalike``: K = 2 and rooms whose trackers differ (``Building.alike``),
  each room planned on its own;
* ``corridor``: rooms in a corridor (each also surveyed to the next), first room's camera to
  the last room's marker (``C0_1 -> M<n-1>``), n = 2, 3, 5, 10, 20, 50, 100, 200, 500, 2000 rooms,
  K = 0;
* ``shared_in_room`` / ``shared_cross_room``: shared targets (each camera also sees the next
  room's marker through the door), in a star of n = 2, 5, 10, 20, 50, 100, 500 rooms; in the
  middle room ``m = n // 2``, ``C<m>_1 -> M<m>``, and from the room before, ``C<m-1>_1 ->
  M<m>`` (a target seen from two rooms);
* ``cross_building``: a star of n = 2, 10, 50, 100, 200, 500, 2000 rooms, first room's camera to
  the last room's marker.

``--quick`` runs a few small rows of most series (``all_series``).

For each row, in a child process (forked, one per row) so that a planner that explodes is
stopped and reported as *over the limit* instead of hanging the run:

* the plan time: ``ubitrack_agent.graph.planner.plan(srg, load_templates(), query)``, run up
  to ``--repeats`` times while the runs so far plus one more stay within the limit (at least
  once); the median is quoted, with the best solution's cost and its steps' patterns;
* side by side, the time of a plain shortest path over the same SRG (:func:`shortest_path`:
  networkx Dijkstra from the query's source to its target on the SRG viewed undirected, over
  the edges of the query's type only, each weighted by the cost of one measured edge, the
  cheapest of parallel edges), median of up to ``SHORTEST_PATH_REPEATS`` runs;
* the ratio plan / shortest path;
* the same three figures in CPU time of the measuring process (``time.process_time``): on a
  machine others share, a process waiting for a core counts in the wall time, not in its CPU
  time, so the CPU figures are the ones to compare across runs (on a quiet machine both agree,
  the planner being one thread that waits for nothing).

A row is *over the limit* when one plan does not finish within ``--limit`` seconds (then the
child is killed). A series stops at its first row over the limit (``broke_at``). The growth
of a series is given between consecutive rows as the time factor per added unit (tracker,
body or room), ``(t2 / t1) ** (1 / (x2 - x1))``, and the milliseconds per added unit,
``(t2 - t1) / (x2 - x1)``: linear growth shows a constant increment and a factor falling
towards 1, exponential growth a constant factor above 1.

The benchmark uses only the planner's public ``plan`` API (``Query``, ``PlanningError``, a
solution's ``cost`` and ``steps``), so it runs unchanged on any planner with that API. The
commit of the checkout, the last commit that changed the planner and the machine's load
average (others may share it) are written with the figures. The benchmark's own cost is the
SRG's construction (O(edges)) and a shortest path (O(E log V)) per row, negligible beside the
plans.
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
import multiprocessing as mp
import os
import platform
import statistics
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Sequence
from contextlib import suppress
from dataclasses import asdict, dataclass
from itertools import pairwise
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import networkx as nx

from bench.building import Building, body, build, camera, marker
from ubitrack_agent.graph.planner import PlanningError, Query, plan
from ubitrack_agent.graph.srg import Quality
from ubitrack_agent.graph.templates import load_templates

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results" / "building.json"
DEFAULT_LIMIT_S = 20.0
DEFAULT_REPEATS = 5
QUICK_REPEATS = 3
SHORTEST_PATH_REPEATS = 50
"""Runs of the shortest path per row (fewer if they take more than a second together)."""
SETUP_TIMEOUT_S = 120.0
"""Longest wait for a row's SRG and shortest path, before its plans (they take milliseconds)."""
PLANNER_PACKAGE = "ubitrack_agent/graph"
BUILDING_ROOMS = 50
"""Rooms of the building of the ``in_building`` series."""

# The cost of one measured edge in the planner's cost model (docs/planner.md): its variance
# in units of (1 mm)^2, its latency in units of 10 ms, and 0.1 for its sensor.
SIGMA_REF_M = 1e-3
LATENCY_REF_S = 0.01
SENSOR_COST = 0.1


@dataclass(frozen=True)
class Row:
    """One measurement: ``query`` on the building ``shape``; ``size`` is the series' variable."""

    series: str
    size: int
    shape: Building
    query: Query


@dataclass(frozen=True)
class Series:
    """Rows of growing ``size`` (counted in ``unit``), measured until the first over the limit."""

    name: str
    unit: str
    rows: tuple[Row, ...]


def edge_weight(quality: Quality) -> float:
    """The cost of one measured edge (the comment above :data:`SIGMA_REF_M`)."""
    return quality.variance / SIGMA_REF_M**2 + quality.latency / LATENCY_REF_S + SENSOR_COST


def shortest_path(srg: nx.MultiDiGraph, query: Query) -> tuple[list[str], float]:
    """The cheapest chain of ``query.type`` edges from ``query.source`` to ``query.target``,
    each edge usable either way (an inversion), as a transform-tree lookup would walk it:
    networkx Dijkstra (``nx.shortest_path``, stopping at the target) on ``srg`` viewed
    undirected, an edge weighted by :func:`edge_weight` (the cheapest of parallel edges, other
    types hidden). Returns the frames of the path and its cost; O(E log V). Raises
    ``networkx.NetworkXNoPath`` if there is none."""

    def weight(u: str, v: str, parallel: dict[str, dict[str, Any]]) -> float | None:
        costs = [edge_weight(d["quality"]) for d in parallel.values() if d["type"] == query.type]
        return min(costs) if costs else None

    undirected = srg.to_undirected(as_view=True)
    path = nx.shortest_path(undirected, query.source, query.target, weight=weight)
    cost = sum(weight(u, v, undirected[u][v]) or 0.0 for u, v in pairwise(path))
    return path, cost


def in_room(k: int, series: str = "in_room") -> Row:
    return Row(series, k, Building(redundant=k), Query(camera(0), marker(0), "6D"))


def in_building(k: int) -> Row:
    shape = Building(rooms=BUILDING_ROOMS, redundant=k)
    return Row("in_building", k, shape, Query(camera(0), marker(0), "6D"))


def head_to_head(bodies: int, k: int, alike: bool = True) -> Row:
    shape = Building(rooms=2, bodies=bodies, redundant=k, alike=alike)
    name = f"head_to_head_k{k}" + ("" if alike else "_unalike")
    return Row(name, bodies, shape, Query(body(0), body(1), "6D"))


def corridor(rooms: int) -> Row:
    shape = Building(rooms=rooms, layout="corridor")
    return Row("corridor", rooms, shape, Query(camera(0), marker(rooms - 1), "6D"))


def shared(rooms: int, cross: bool) -> Row:
    """Shared targets in a star of ``rooms``: the middle room's marker from its own camera, or
    (``cross``) from the camera of the room before it."""
    m = rooms // 2
    name = "shared_cross_room" if cross else "shared_in_room"
    query = Query(camera(m - 1 if cross else m), marker(m), "6D")
    return Row(name, rooms, Building(rooms=rooms, shared_targets=True), query)


def cross_building(rooms: int) -> Row:
    return Row(
        "cross_building", rooms, Building(rooms=rooms), Query(camera(0), marker(rooms - 1), "6D")
    )


def all_series(quick: bool) -> list[Series]:
    """The series of the module docstring; ``quick``: a few small rows of each kind."""
    if quick:
        return [
            Series("in_room", "tracker", tuple(in_room(k) for k in (0, 1, 2))),
            Series("in_building", "tracker", (in_building(2),)),
            Series("head_to_head_k1", "body", tuple(head_to_head(b, 1) for b in (1, 2))),
            Series("corridor", "room", tuple(corridor(n) for n in (1, 2))),
            Series("shared_in_room", "room", (shared(2, cross=False),)),
            Series("shared_cross_room", "room", (shared(2, cross=True),)),
            Series("cross_building", "room", tuple(cross_building(n) for n in (2, 10))),
        ]
    rooms = (2, 5, 10, 20, 50, 100)
    bodies = (1, 2, 3, 4, 5, 6, 8, 10, 15, 20)
    trackers = (0, 2, 5, 7, 10, 15, 20, 30, 50, 100, 200, 500)
    return [
        Series("in_room", "tracker", tuple(in_room(k) for k in trackers)),
        Series(
            "in_room_large",
            "tracker",
            tuple(in_room(k, "in_room_large") for k in (1000, 2000, 5000)),
        ),
        Series("in_building", "tracker", tuple(in_building(k) for k in (2, 4, 10, 20))),
        Series("head_to_head_k1", "body", tuple(head_to_head(b, 1) for b in bodies)),
        Series(
            "head_to_head_k2", "body", tuple(head_to_head(b, 2) for b in (*bodies, 30, 50, 100))
        ),
        Series("head_to_head_k5", "body", tuple(head_to_head(b, 5) for b in (1, 2, 4, 8, 16, 32))),
        Series(
            "head_to_head_k10", "body", tuple(head_to_head(b, 10) for b in (1, 2, 4, 8, 16, 32))
        ),
        Series(
            "head_to_head_k2_unalike",
            "body",
            tuple(head_to_head(b, 2, alike=False) for b in bodies),
        ),
        Series("corridor", "room", tuple(corridor(n) for n in (2, 3, *rooms[1:], 200, 500, 2000))),
        Series("shared_in_room", "room", tuple(shared(n, cross=False) for n in (*rooms, 500))),
        Series("shared_cross_room", "room", tuple(shared(n, cross=True) for n in (*rooms, 500))),
        Series(
            "cross_building",
            "room",
            tuple(cross_building(n) for n in (2, 10, 50, 100, 200, 500, 2000)),
        ),
    ]


def _planner_of(root: Path | None) -> tuple[Any, Any, type[Exception]]:
    """``plan``, ``load_templates`` and ``PlanningError`` of this checkout, or (in a child
    process only) of the checkout at ``root``: the package is imported again from there."""
    if root is None:
        return plan, load_templates, PlanningError
    for name in [n for n in sys.modules if n.split(".")[0] in ("ubitrack_agent", "templates")]:
        del sys.modules[name]
    sys.path.insert(0, str(root))
    planner = importlib.import_module("ubitrack_agent.graph.planner")
    catalogue = importlib.import_module("ubitrack_agent.graph.templates")
    return planner.plan, catalogue.load_templates, planner.PlanningError


def _measure_in_child(
    send: Connection, row: Row, repeats: int, limit_s: float, root: Path | None
) -> None:
    """In the child: build the SRG, time the shortest path, then the plans (of the planner at
    ``root`` if given, :func:`_planner_of`), sending each figure as it is known (so the parent
    keeps what finished if it has to kill the child)."""
    srg = build(row.shape)
    plan, load_templates, PlanningError = _planner_of(root)
    templates = load_templates()
    send.send(("graph", srg.number_of_nodes(), srg.number_of_edges()))
    times: list[float] = []
    cpu_times: list[float] = []
    path, path_cost = [], math.nan
    for _ in range(SHORTEST_PATH_REPEATS):
        start, start_cpu = time.perf_counter(), time.process_time()
        with suppress(nx.NetworkXNoPath):
            path, path_cost = shortest_path(srg, row.query)
        cpu_times.append(time.process_time() - start_cpu)
        times.append(time.perf_counter() - start)
        if sum(times) > 1.0:
            break
    send.send(
        (
            "shortest_path",
            statistics.median(times) * 1e3,
            statistics.median(cpu_times) * 1e3,
            len(path) - 1,
            path_cost,
        )
    )
    elapsed = 0.0
    for _ in range(repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        try:
            found = plan(srg, templates, row.query)
        except PlanningError as exc:
            send.send(("error", str(exc)))
            break
        took_cpu = time.process_time() - start_cpu
        took = time.perf_counter() - start
        best = found[0]
        patterns = [step.template.pattern for step in best.steps]
        send.send(("plan", took * 1e3, took_cpu * 1e3, best.cost, patterns, len(found)))
        elapsed += took
        if elapsed + took > limit_s:
            break
    send.send(("done",))


def measure(
    row: Row, repeats: int, limit_s: float, root: Path | None = None, processes: int = 1
) -> dict[str, Any]:
    """The figures of ``row`` (module docstring), measured in ``processes`` forked children one
    after the other (the plans of all pooled: a process's speed differs from another's on a
    shared machine, by up to 1.7x here with the work the same), each killed when one plan
    takes over ``limit_s`` seconds; with ``root``, of the planner there."""
    result: dict[str, Any] = {
        "series": row.series,
        "size": row.size,
        "setup": asdict(row.shape),
        "query": f"{row.query.source}->{row.query.target} {row.query.type}",
        "plan_ms": None,
        "plan_runs": 0,
        "over_limit": False,
        "error": None,
    }
    plans: list[float] = []
    plans_cpu: list[float] = []
    per_process: list[float] = []
    for _ in range(processes):
        timed, timed_cpu = _measure_in_a_child(result, row, repeats, limit_s, root)
        plans += timed
        plans_cpu += timed_cpu
        if timed:
            per_process.append(round(statistics.median(timed), 3))
        if result["over_limit"] or result["error"]:
            break
    if plans and not result["over_limit"]:
        result["plan_ms"] = round(statistics.median(plans), 3)
        result["plan_cpu_ms"] = round(statistics.median(plans_cpu), 3)
        result["plan_runs"] = len(plans)
        if processes > 1:
            result["plan_ms_per_process"] = per_process
        shortest = result.get("shortest_path_ms")
        result["ratio"] = round(result["plan_ms"] / shortest, 1) if shortest else None
        shortest_cpu = result.get("shortest_path_cpu_ms")
        result["ratio_cpu"] = (
            round(result["plan_cpu_ms"] / shortest_cpu, 1) if shortest_cpu else None
        )
    return result


def _measure_in_a_child(
    result: dict[str, Any], row: Row, repeats: int, limit_s: float, root: Path | None
) -> tuple[list[float], list[float]]:
    """One forked child's plans of ``row`` (wall and CPU ms); what else it reports (the graph,
    the shortest path, the best derivation, errors, the limit) goes into ``result``."""
    context = mp.get_context("fork")
    receive, send = context.Pipe(duplex=False)
    child = context.Process(target=_measure_in_child, args=(send, row, repeats, limit_s, root))
    child.start()
    send.close()
    plans: list[float] = []
    plans_cpu: list[float] = []
    planning = False  # the limit counts from the first plan on, not while the SRG is built
    while True:
        if not receive.poll(limit_s if planning else SETUP_TIMEOUT_S):
            result["over_limit"] = planning
            result["error"] = None if planning else "building the SRG took too long"
            break
        try:
            message = receive.recv()
        except EOFError:
            result["error"] = "the measuring process ended early"
            break
        kind, *values = message
        if kind == "done":
            break
        if kind == "graph":
            result["setup"]["frames"], result["setup"]["edges"] = values
        elif kind == "shortest_path":
            ms, cpu_ms, hops, cost = values
            result["shortest_path_ms"] = round(ms, 4)
            result["shortest_path_cpu_ms"] = round(cpu_ms, 4)
            result["shortest_path_hops"] = hops
            result["shortest_path_cost"] = None if math.isnan(cost) else round(cost, 6)
            planning = True
        elif kind == "error":
            result["error"] = values[0]
        else:
            ms, cpu_ms, cost, patterns, count = values
            plans.append(ms)
            plans_cpu.append(cpu_ms)
            result.update(best_cost=round(cost, 6), best_steps=patterns, solutions=count)
    if child.is_alive():
        child.kill()
    child.join()
    receive.close()
    return plans, plans_cpu


def growth(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Between consecutive measured rows: the time factor and the ms per added unit."""
    timed = [r for r in rows if r["plan_ms"]]
    steps = []
    for a, b in pairwise(timed):
        units = b["size"] - a["size"]
        steps.append(
            {
                "from": a["size"],
                "to": b["size"],
                "factor_per_unit": round((b["plan_ms"] / a["plan_ms"]) ** (1 / units), 3),
                "ms_per_unit": round((b["plan_ms"] - a["plan_ms"]) / units, 3),
            }
        )
    return steps


def steps_summary(patterns: Sequence[str]) -> str:
    """``patterns`` counted, most frequent first: ``"Concatenation x4, Inversion x3, ..."``."""
    counts = Counter(patterns).most_common()
    return ", ".join(name if n == 1 else f"{name} x{n}" for name, n in counts)


def table_line(result: dict[str, Any], limit_s: float) -> str:
    setup = result["setup"]
    if result["over_limit"]:
        planned = f"over {limit_s:g} s"
    elif result["plan_ms"] is None:
        planned = f"error: {result['error']}"
    else:
        planned = f"{result['plan_ms']:.1f} ms"
        cpu = f"{result['plan_cpu_ms']:.1f} ms"
    ratio = result.get("ratio")
    shortest = result.get("shortest_path_ms")
    cost = result.get("best_cost")
    if "before_plan_ms" in result:
        then = result["before_plan_ms"]
        then = f"over {limit_s:g} s" if result["before_over_limit"] else f"{then:.1f} ms"
        cost_then = result["before_best_cost"]
        planned += f" (before {then}, cost {'-' if cost_then is None else f'{cost_then:.3f}'})"
    ratio_cpu = result.get("ratio_cpu")
    return (
        f"{result['series']:<18} {result['size']:>4} {setup.get('frames', '?'):>5}/"
        f"{setup.get('edges', '?'):<5} {result['query']:<16} {planned:>12} "
        f"{'-' if shortest is None else f'{shortest:.3f} ms':>11} "
        f"{'-' if ratio is None else f'{ratio:g}x':>9} "
        f"{'-' if result['plan_ms'] is None else cpu:>10} "
        f"{'-' if ratio_cpu is None else f'{ratio_cpu:g}x':>9} "
        f"{'-' if cost is None else f'{cost:.3f}':>7}  "
        + steps_summary(result.get("best_steps", []))
    )


def growth_line(series: Series, steps: Sequence[dict[str, Any]], broke_at: int | None) -> str:
    parts = [
        f"{s['from']}->{s['to']}: x{s['factor_per_unit']:g}/{series.unit} "
        f"({s['ms_per_unit']:+.1f} ms/{series.unit})"
        for s in steps
    ]
    if broke_at is not None:
        parts.append(f"over the limit at {broke_at}")
    return f"  growth of {series.name}: " + ("; ".join(parts) or "(one point)")


def checkout_commits() -> dict[str, str]:
    """The commit of this checkout and the last one that changed the planner's package
    (``+dirty`` if its files differ from it), or ``unknown`` outside a git checkout."""

    def git(*args: str) -> str:
        done = subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True)
        if done.returncode:
            raise OSError(done.stderr)
        return done.stdout.strip()

    try:
        head = git("rev-parse", "--short", "HEAD")
        planner = git("log", "-1", "--format=%h", "--", PLANNER_PACKAGE)
        dirty = git("status", "--porcelain", PLANNER_PACKAGE)
    except OSError:
        return {"commit": "unknown", "planner_commit": "unknown"}
    return {"commit": head, "planner_commit": planner + ("+dirty" if dirty else "")}


def compared(result: dict[str, Any], before: dict[str, Any]) -> dict[str, Any]:
    """``result`` with the figures of the planner compared with (``before``) beside it."""
    ms = None if before["over_limit"] else before["plan_ms"]
    now = result["plan_ms"]
    return {
        **result,
        "before_plan_ms": ms,
        "before_plan_cpu_ms": None if before["over_limit"] else before.get("plan_cpu_ms"),
        "before_over_limit": before["over_limit"],
        "before_best_cost": before.get("best_cost"),
        "speed_up": round(ms / now, 1) if ms and now else None,
    }


def run(
    series: Sequence[Series],
    repeats: int,
    limit_s: float,
    before: Path | None = None,
    processes: int = 1,
) -> dict[str, Any]:
    """Measure every series (each until its first row over the limit), printing as it goes;
    with ``before``, each row also on the planner of that checkout, right after; each row in
    ``processes`` processes."""
    results: dict[str, Any] = {
        "date": time.strftime("%Y-%m-%d"),
        "python": platform.python_version(),
        "machine": platform.machine(),
        **checkout_commits(),
        "limit_s": limit_s,
        "repeats": repeats,
        "processes": processes,
        "load_average_1min": {"start": os.getloadavg()[0]},
        "compared_with": str(before) if before else None,
        "rows": [],
        "series": {},
    }
    print(
        f"{'series':<18} {'size':>4} {'frames/edges':<11} {'query':<16} {'plan':>12} "
        f"{'shortest':>11} {'ratio':>9} {'plan cpu':>10} {'cpu ratio':>9} {'cost':>7}  "
        "best steps",
        flush=True,
    )
    for s in series:
        rows = []
        broke_at = None
        for row in s.rows:
            result = measure(row, repeats, limit_s, processes=processes)
            if before is not None:
                result = compared(
                    result, measure(row, repeats, limit_s, before, processes=processes)
                )
            rows.append(result)
            print(table_line(result, limit_s), flush=True)
            if result["over_limit"]:
                broke_at = row.size
                break
        steps = growth(rows)
        print(growth_line(s, steps, broke_at), flush=True)
        results["rows"].extend(rows)
        results["series"][s.name] = {
            "unit": s.unit,
            "sizes": [r["size"] for r in rows],
            "plan_ms": [r["plan_ms"] for r in rows],
            "plan_cpu_ms": [r.get("plan_cpu_ms") for r in rows],
            "shortest_path_ms": [r.get("shortest_path_ms") for r in rows],
            "growth": steps,
            "broke_at": broke_at,
        }
    results["load_average_1min"]["end"] = os.getloadavg()[0]
    return results


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a few small rows (a smoke run)")
    parser.add_argument(
        "--limit",
        type=float,
        default=DEFAULT_LIMIT_S,
        help=f"seconds one plan may take before its row is over (default {DEFAULT_LIMIT_S:g})",
    )
    parser.add_argument(
        "--repeats",
        type=int,
        help=f"plans per row (default {DEFAULT_REPEATS}, {QUICK_REPEATS} with --quick)",
    )
    parser.add_argument(
        "--series", help="comma-separated series to run (default all; names in the docstring)"
    )
    parser.add_argument(
        "--compare-with",
        type=Path,
        metavar="DIR",
        help="also plan each row with the planner of the checkout in DIR (e.g. a git worktree "
        "of an older commit), right after, for figures side by side in one run",
    )
    parser.add_argument(
        "--processes",
        type=int,
        default=1,
        help="plan each row in this many processes one after the other, their plans pooled "
        "(a process may run up to 1.7x slower than another on a shared machine; default 1)",
    )
    parser.add_argument(
        "--out", type=Path, default=RESULTS, help=f"JSON file (default {RESULTS.relative_to(ROOT)})"
    )
    args = parser.parse_args(argv)
    repeats = args.repeats or (QUICK_REPEATS if args.quick else DEFAULT_REPEATS)
    chosen = all_series(args.quick)
    if args.series:
        wanted = set(args.series.split(","))
        unknown = wanted - {s.name for s in chosen}
        if unknown:
            parser.error(f"unknown series {', '.join(sorted(unknown))}")
        chosen = [s for s in chosen if s.name in wanted]
    if args.compare_with and not (args.compare_with / "ubitrack_agent" / "graph").is_dir():
        parser.error(f"--compare-with {args.compare_with}: no ubitrack_agent/graph there")
    results = run(chosen, max(1, repeats), args.limit, args.compare_with, max(1, args.processes))
    results["quick"] = args.quick
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")
    print(f"written to {args.out}")


if __name__ == "__main__":
    main()
