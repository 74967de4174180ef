"""The agent's replanning per event, offline: incremental replanning against replanning every
relation, side by side in one run (issue [scale], "An agent that replans what changed").

The SRG is a generated building (``bench.building``; by default 25 rooms, 2 bodies and a
redundant tracker per room, 2 cameras seeing their room's and the next room's 7-feature
target: 100 sensor providers and a database, 1,161 edges) announced as the live agent receives
it: one fragment per provider (``announcements.build_srg``). 100 queries, four per room: head to
head, head to the building, tracker to head, camera to head. Each event makes a provider vanish
or come back; for each, the agent's planning step is timed both ways, from the same previous
plan, with the running components of that plan:

* ``incremental``: ``agent.planning.make_outcome`` (build the SRG, ``agent.replanning.replan``,
  the worker specifications when the plan changed): what the agent runs now;
* ``everything``: build the SRG, ``agent.flows.plan_relations`` over every relation, the worker
  specifications (``materialise.component_specs`` + ``fold``): what the agent ran before.

Then a 101st query is added, timed both ways. Run::

    .venv/bin/python -m bench.agent_replan_bench            # writes bench/results/agent_replan.json
    .venv/bin/python -m bench.agent_replan_bench --rooms 5 --events 4   # a quick look

Each figure is one wall-clock run of the step on this machine (the planner is deterministic);
medians and maxima over the events are printed side by side.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import statistics
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

from bench.building import Building, body, build, camera, tracker
from ubitrack_agent.agent.announcements import build_srg
from ubitrack_agent.agent.flows import plan_relations
from ubitrack_agent.agent.materialise import component_specs, fold
from ubitrack_agent.agent.planning import Outcome, Request, make_outcome
from ubitrack_agent.graph.templates import load_templates
from ubitrack_agent.net.keys import KeySpace, RelationId

RESULTS = Path(__file__).parent / "results" / "agent_replan.json"
KEYS = KeySpace("ubitrack/bench")


def fragments_of(shape: Building) -> dict[str, list[dict[str, Any]]]:
    """The building's edges as the providers announce them (entries of
    ``announcements.provider_entries``: ids ``<provider>/<name>``)."""
    fragments: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for source, target, data in build(shape).edges(data=True):
        provider, quality = data["provider"], data["quality"]
        entry = {
            "id": f"{provider}/{source}_{target}",
            "provider": provider,
            "from": source,
            "to": target,
            "type": data["type"],
            "static": data["static"],
            "mode": data["mode"],
            "sigma": math.sqrt(quality.variance),
            "latency": quality.latency,
        }
        if quality.rate:
            entry["rate"] = quality.rate
        fragments[provider].append(entry)
    return dict(fragments)


def queries_of(shape: Building) -> list[RelationId]:
    """Four queries per room (module docstring)."""
    return [
        relation
        for r in range(shape.rooms)
        for relation in (
            RelationId(body(r, 1), body(r, 2), "6D"),
            RelationId(body(r, 1), "B", "6D"),
            RelationId(tracker(r), body(r, 2), "6D"),
            RelationId(camera(r, 1), body(r, 2), "6D"),
        )
    ]


def everything(request: Request, templates) -> float:
    """The agent's step before incremental replanning (module docstring), timed."""
    started = time.perf_counter()
    srg = build_srg(request.fragments, without=request.stale)
    plan = plan_relations(srg, templates, request.relations, request.running)
    fold(component_specs(plan.flow, srg, KEYS, plan.relations))
    return time.perf_counter() - started


def request_of(generation: int, fragments, relations, previous: Outcome | None) -> Request:
    running = frozenset(previous.planned.plan.flow.components) if previous else frozenset()
    return Request(generation, dict(fragments), frozenset(), frozenset(relations), running, True)


def run(shape: Building, events: int, templates) -> dict[str, Any]:
    fragments = fragments_of(shape)
    relations = queries_of(shape)
    edges = sum(len(entries) for entries in fragments.values())
    print(
        f"building: {shape.rooms} rooms, {len(fragments)} providers, {edges} edges, "
        f"{len(relations)} queries"
    )
    started = time.perf_counter()
    current = make_outcome(request_of(0, fragments, relations, None), None, templates, KEYS)
    first_s = time.perf_counter() - started
    unsolved = len(current.planned.plan.unsolved)
    print(f"first plan of every query: {first_s:.2f} s ({unsolved} unsolved)")
    sensors = sorted(p for p in fragments if p != "database")
    step = max(1, len(sensors) // max(1, events // 2))
    chosen = sensors[::step][: max(1, events // 2)]
    rows = []
    live = dict(fragments)
    for n, (provider, gone) in enumerate(((p, g) for p in chosen for g in (True, False)), 1):
        if gone:
            del live[provider]
        else:
            live[provider] = fragments[provider]
        request = request_of(n, live, relations, current)
        outcome = make_outcome(request, current, templates, KEYS)
        full_s = everything(request, templates)
        rows.append(
            {
                "event": f"{provider} {'vanishes' if gone else 'comes back'}",
                "incremental_s": outcome.seconds,
                "replanned": len(outcome.planned.replanned),
                "everything_s": full_s,
            }
        )
        print(
            f"  {rows[-1]['event']:<24} incremental {1e3 * outcome.seconds:8.1f} ms "
            f"({len(outcome.planned.replanned):3d} replanned)   everything {1e3 * full_s:8.1f} ms"
        )
        current = outcome
    added = RelationId(body(0, 2), tracker(0, 1), "6D")
    request = request_of(len(rows) + 1, live, [*relations, added], current)
    one = make_outcome(request, current, templates, KEYS)
    added_full_s = everything(request, templates)
    print(
        f"a query added among {len(relations)}: incremental {1e3 * one.seconds:.1f} ms "
        f"({len(one.planned.replanned)} planned), everything {1e3 * added_full_s:.1f} ms"
    )
    return {
        "shape": shape.__dict__,
        "providers": len(fragments),
        "edges": edges,
        "queries": len(relations),
        "unsolved": unsolved,
        "first_plan_s": first_s,
        "events": rows,
        "summary": summary(rows),
        "query_added": {
            "incremental_s": one.seconds,
            "planned": len(one.planned.replanned),
            "everything_s": added_full_s,
        },
    }


def summary(rows: list[dict[str, Any]]) -> dict[str, dict[str, float]]:
    return {
        way: {
            "median_s": statistics.median(r[f"{way}_s"] for r in rows),
            "max_s": max(r[f"{way}_s"] for r in rows),
        }
        for way in ("incremental", "everything")
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rooms", type=int, default=25)
    parser.add_argument("--events", type=int, default=10, help="provider events (even)")
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    shape = Building(
        rooms=args.rooms, bodies=2, redundant=1, cameras=2, features=7, shared_targets=True
    )
    result = run(shape, args.events, load_templates())
    for way, figures in result["summary"].items():
        print(
            f"{way:>12}: median {1e3 * figures['median_s']:.1f} ms, "
            f"max {1e3 * figures['max_s']:.1f} ms per provider event"
        )
    result["machine"] = f"{platform.machine()}, {platform.python_version()}"
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
