"""Every alternative of every plan on a broad case set, to compare two planners byte for byte
(issue [scale]: a faster search must give exactly the same answers).

Run as ``python -m bench.plan_answers dump OUT.json [--random N] [--only KIND]`` to write, per
case, the ``as_json`` of each solution ``graph.planner.plan`` returns (or the error it raises),
and ``python -m bench.plan_answers compare A.json B.json`` to count the cases whose answers are
identical (exit status 1 if any differ). The planner is the one imported: to dump an older
checkout's answers, run with ``PYTHONPATH=<checkout>`` (the module prints which planner file it
loaded on stderr). Use the same ``PYTHONHASHSEED`` for both dumps.

The cases (``KIND``):

* ``rows``: rows of :mod:`bench.building_bench` (:func:`benchmark_rows`: K up to 100 in a
  room, head to head up to 10 bodies with K = 1, 2 and up to 4 with K = 5, 10);
* ``shapes``: 64 building shapes of :mod:`bench.building` (1-2 rooms, 1-2 bodies, 0-1
  redundant trackers, 0 or 4 features, star or corridor, shared targets or not), each with a
  camera -> marker, a head -> head (or head -> room) and a static calibration query, at
  ``per_relation`` 8 and 16 (the shapes of ``tests/unit/test_planner_oracle.py``);
* ``random``: ``N`` seeded random multigraphs (default 800) of 5-6 frames and 3-13 edges of
  mixed types, static and dynamic, a 6D query between two random frames (static with
  probability 0.3), at ``per_relation`` 8 and 16.

Cost: one plan per case; the rows dominate (a few seconds each at most).
"""

from __future__ import annotations

import argparse
import itertools
import json
import random
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import networkx as nx

from bench import building_bench
from bench.building import Building, body, build, camera, marker, room
from ubitrack_agent.graph import planner
from ubitrack_agent.graph.planner import PlanningError, Query, plan
from ubitrack_agent.graph.srg import add_measured_edge, new_srg
from ubitrack_agent.graph.templates import load_templates

KINDS = ("rows", "shapes", "random")
RANDOM_TYPES = ("6D", "6D", "6D", "3D", "2D", "3x4")


def _answers(templates: Sequence, srg, query: Query, **options: Any) -> list | str:
    try:
        return [s.as_json() for s in plan(srg, templates, query, **options)]
    except PlanningError as error:
        return f"error: {type(error).__name__}: {error}"


def benchmark_rows() -> list[building_bench.Row]:
    """The rows of :mod:`bench.building_bench` up to the sizes an older checkout's benchmark
    has too (its row functions, not its list of series, so both dump the same cases)."""
    b = building_bench
    rooms = (2, 5, 10, 20, 50, 100)
    bodies = (1, 2, 3, 4, 5, 6, 8, 10)
    return [
        *(b.in_room(k) for k in (0, 2, 5, 7, 10, 15, 20, 30, 50, 100)),
        *(b.in_building(k) for k in (2, 4, 10)),
        *(b.head_to_head(n, k) for k in (1, 2) for n in bodies),
        *(b.head_to_head(n, k) for k in (5, 10) for n in (1, 2, 4)),
        *(b.head_to_head(n, 2, alike=False) for n in bodies),
        *(b.corridor(n) for n in (2, 3, *rooms[1:], 200)),
        *(b.shared(n, cross) for cross in (False, True) for n in rooms),
        *(b.cross_building(n) for n in (2, 10, 50, 100, 200)),
    ]


def row_cases(run: Callable[..., None]) -> None:
    for row in benchmark_rows():
        run(f"row:{row.series}:{row.size}", build(row.shape), row.query)


def shape_cases(run: Callable[..., None]) -> None:
    for rooms, bodies, redundant, features, layout, shared in itertools.product(
        (1, 2), (1, 2), (0, 1), (0, 4), ("star", "corridor"), (False, True)
    ):
        shape = Building(
            rooms=rooms,
            bodies=bodies,
            redundant=redundant,
            cameras=1,
            features=features,
            layout=layout,
            shared_targets=shared,
        )
        srg = build(shape)
        last = rooms - 1
        other = body(last, 2) if last == 0 and bodies > 1 else body(last)
        queries = {
            "camera_marker": Query(camera(0), marker(last), "6D"),
            "head_head": Query(body(0), other if other != body(0) else room(0), "6D"),
            "calibration": Query(camera(0), body(0), "6D", static=True),
        }
        for kind, query in queries.items():
            run(f"shape:{shape}:{kind}", srg, query)
            run(f"shape:{shape}:{kind}:all16", srg, query, per_relation=16)


def random_case(seed: int) -> tuple[nx.MultiDiGraph, Query] | None:
    """The random multigraph and query of case ``random:SEED`` (``None``: a query frame has
    no edge, no case)."""
    rng = random.Random(seed)
    n = rng.choice((5, 6))
    srg = new_srg()
    for _ in range(rng.randint(3, 13)):
        a, b = rng.sample(range(n), 2)
        kind = rng.choice(RANDOM_TYPES)
        add_measured_edge(srg, f"N{a}", f"N{b}", kind, static=rng.random() < 0.4)
    a, b = rng.sample(range(n), 2)
    if f"N{a}" not in srg or f"N{b}" not in srg:
        return None
    return srg, Query(f"N{a}", f"N{b}", "6D", rng.random() < 0.3)


def random_cases(run: Callable[..., None], count: int) -> None:
    for seed in range(count):
        case = random_case(seed)
        if case is not None:
            for per_relation in (8, 16):
                run(f"random:{seed}:{per_relation}", *case, per_relation=per_relation)


def dump(out: Path, kinds: Sequence[str], random_count: int) -> dict[str, Any]:
    print(f"planner from {planner.__file__}", file=sys.stderr)
    templates = load_templates()
    found: dict[str, Any] = {}

    def run(name: str, srg, query: Query, **options: Any) -> None:
        found[name] = _answers(templates, srg, query, **options)

    start = time.monotonic()
    for kind in kinds:
        if kind == "rows":
            row_cases(run)
        elif kind == "shapes":
            shape_cases(run)
        else:
            random_cases(run, random_count)
        print(f"{kind}: {len(found)} cases, {time.monotonic() - start:.0f} s", file=sys.stderr)
    out.write_text(json.dumps(found, sort_keys=True))
    return found


def compare(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    """The cases whose answers differ (or that only one file has)."""
    differ = sorted(set(a) ^ set(b))
    differ += [k for k in sorted(set(a) & set(b)) if json.dumps(a[k]) != json.dumps(b[k])]
    return differ


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    dumping = sub.add_parser("dump", help="write every case's answers")
    dumping.add_argument("out", type=Path)
    dumping.add_argument("--random", type=int, default=800, help="random multigraphs")
    dumping.add_argument("--only", choices=KINDS, action="append", help="case kinds")
    comparing = sub.add_parser("compare", help="compare two dumps")
    comparing.add_argument("a", type=Path)
    comparing.add_argument("b", type=Path)
    args = parser.parse_args(argv)
    if args.command == "dump":
        dump(args.out, args.only or KINDS, args.random)
        return 0
    a, b = (json.loads(path.read_text()) for path in (args.a, args.b))
    differ = compare(a, b)
    solutions = sum(len(v) for v in a.values() if isinstance(v, list))
    print(
        f"{len(a)} cases, {solutions} solutions: {len(a) - len(differ)} identical, "
        f"{len(differ)} differ"
    )
    for name in differ[:20]:
        print(f"differs: {name}")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
