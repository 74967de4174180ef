"""The building benchmark (``bench/building_bench.py``): its shortest path, its growth figures,
a row stopped over its limit, and a quick run writing the JSON the docs quote."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import networkx as nx
import pytest

from bench.building import Building, body, build, camera, marker, room, tracker
from bench.building_bench import all_series, compared, corridor, growth, measure, shortest_path
from ubitrack_agent.graph.planner import Query

ROOT = Path(__file__).resolve().parents[2]


def test_the_shortest_path_walks_edges_of_the_query_type_either_way() -> None:
    path, cost = shortest_path(build(Building()), Query(camera(0), marker(0), "6D"))
    assert path == [camera(0), body(0), tracker(0), room(0), marker(0)]
    # three surveys (1 mm: 1 + 0.1 for the database) and the tracker (0.5 mm, 5 ms, + 0.1)
    assert cost == pytest.approx(3 * 1.1 + (0.25 + 0.5 + 0.1))


def test_the_shortest_path_ignores_edges_of_other_types() -> None:
    srg = build(Building())
    # the only 2D edges join images to features: no 2D chain joins a camera to a marker
    with pytest.raises(nx.NetworkXNoPath):
        shortest_path(srg, Query(camera(0), marker(0), "2D"))


def test_growth_gives_the_factor_and_the_milliseconds_per_added_unit() -> None:
    rows = [
        {"size": 0, "plan_ms": 10.0},
        {"size": 2, "plan_ms": 40.0},
        {"size": 3, "plan_ms": None},  # over the limit: no figure
    ]
    assert growth(rows) == [{"from": 0, "to": 2, "factor_per_unit": 2.0, "ms_per_unit": 15.0}]


def test_a_plan_over_the_limit_is_stopped_and_reported() -> None:
    # no planner derives a five-room corridor's cross query in 0.1 ms
    result = measure(corridor(5), repeats=3, limit_s=1e-4)
    assert result["over_limit"] and result["plan_ms"] is None and result["error"] is None
    assert (
        result["setup"]["frames"] == build(Building(rooms=5, layout="corridor")).number_of_nodes()
    )
    assert result["shortest_path_hops"] == 6  # C0-H0-T0-R0-B-R4-M4


def test_a_quick_run_writes_every_series_with_its_rows(tmp_path: Path) -> None:
    out = tmp_path / "building.json"
    command = [sys.executable, "-m", "bench.building_bench", "--quick", "--limit", "5"]
    subprocess.run(
        [*command, "--repeats", "1", "--out", str(out)], cwd=ROOT, check=True, timeout=120
    )
    results = json.loads(out.read_text())
    assert set(results) >= {
        "commit",
        "planner_commit",
        "limit_s",
        "repeats",
        "rows",
        "series",
        "quick",
    }
    assert list(results["series"]) == [s.name for s in all_series(quick=True)]
    for row in results["rows"]:
        assert row["error"] is None, row
        assert set(row) >= {"series", "size", "setup", "query", "plan_ms", "shortest_path_ms"}
        if row["over_limit"]:
            continue
        assert row["plan_ms"] > 0 and row["best_steps"] and row["ratio"] > 0
        assert row["plan_cpu_ms"] > 0 and row["ratio_cpu"] > 0
        assert row["best_cost"] > 0 and row["shortest_path_hops"] >= 1
    for name, series in results["series"].items():
        rows = [r for r in results["rows"] if r["series"] == name]
        assert series["sizes"] == [r["size"] for r in rows]
        assert series["broke_at"] in (None, rows[-1]["size"])


def test_a_row_compared_with_the_planner_before_it():
    now = {"plan_ms": 20.0, "over_limit": False}
    before = {"plan_ms": 500.0, "over_limit": False, "best_cost": 4.2}
    row = compared(now, before)
    assert (row["before_plan_ms"], row["before_best_cost"], row["speed_up"]) == (500.0, 4.2, 25.0)
    over = compared(now, {"plan_ms": None, "over_limit": True})
    assert over["before_over_limit"] and over["speed_up"] is None
