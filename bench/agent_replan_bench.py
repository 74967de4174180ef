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
* ``memoised``: the same, with the planner's answers memoised by region
  (``agent.plan_memo``, as the agent runs it), on a chain of plans of its own (the plans are
  checked equal);
* ``everything``: build the SRG, ``agent.flows.plan_relations`` over every relation, the worker
  specifications (``materialise.component_specs``): what the agent ran before.

Then a 101st query is added, timed the three ways; for the incremental steps, the time of
``agent.replanning.replan`` alone is given beside the whole step's (the rest builds the SRG and
the worker specifications). Last, a worker nothing ran appears: one that is a component of a
derivation within the cost margin of some relation (its relations are planned again), then one
no derivation uses (none is). Run::

    .venv/bin/python -m bench.agent_replan_bench            # writes bench/results/agent_replan.json
    .venv/bin/python -m bench.agent_replan_bench --rooms 5 --events 4   # a quick look

Each incremental figure is the fastest of ``--repeat`` wall-clock runs of the step (the planner
is deterministic; the machine is shared), ``everything`` one run; medians and maxima over the
events are printed side by side.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

from bench.building import Building, body, build, camera, tracker
from ubitrack_agent.agent.announcements import build_srg
from ubitrack_agent.agent.flows import plan_relations
from ubitrack_agent.agent.materialise import component_specs
from ubitrack_agent.agent.plan_memo import PlanMemo
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
    component_specs(plan.flow, srg, KEYS, plan.relations)
    return time.perf_counter() - started


def request_of(generation: int, fragments, relations, previous: Outcome | None) -> Request:
    running = frozenset(previous.planned.plan.flow.components) if previous else frozenset()
    return Request(generation, dict(fragments), frozenset(), frozenset(relations), running, True)


def timed_step(
    request: Request, current: Outcome, templates, memo: PlanMemo | None, repeat: int
) -> tuple[Outcome, PlanMemo | None]:
    """The agent's planning step, incremental from ``current`` (with ``memo``, if any), made
    ``repeat`` times: the outcome of the fastest (each time from a copy of ``memo`` as it was,
    so no run answers from another's plans), and the memo it left."""
    made = []
    for _ in range(repeat):
        copy = memo.copy() if memo else None
        outcome = make_outcome(request, current, templates, KEYS, *([copy] if copy else []))
        made.append((outcome.seconds, outcome, copy))
    _, outcome, copy = min(made, key=lambda item: item[0])
    return outcome, copy


def run(shape: Building, events: int, templates, repeat: int) -> dict[str, Any]:
    fragments = fragments_of(shape)
    relations = queries_of(shape)
    edges = sum(len(entries) for entries in fragments.values())
    print(
        f"building: {shape.rooms} rooms, {len(fragments)} providers, {edges} edges, "
        f"{len(relations)} queries"
    )
    memo = PlanMemo()
    started = time.perf_counter()
    current = make_outcome(request_of(0, fragments, relations, None), None, templates, KEYS)
    first_s = time.perf_counter() - started
    memoised = make_outcome(request_of(0, fragments, relations, None), None, templates, KEYS, memo)
    unsolved = len(current.planned.plan.unsolved)
    spares = getattr(current.planned.plan.flow, "spares", {})  # none before agent.spares
    counts = {
        "components": len(current.wanted),
        "spare_producers": sum(len(producers) for producers in spares.values()),
        "relations_with_spares": len(spares),
    }
    print(
        f"first plan of every query: {first_s:.2f} s ({unsolved} unsolved); "
        f"{counts['components']} components, {counts['spare_producers']} spare producers of "
        f"{counts['relations_with_spares']} relations"
    )
    sensors = sorted(p for p in fragments if p != "database")
    step = max(1, len(sensors) // max(1, events // 2))
    chosen = sensors[::step][: max(1, events // 2)]
    rows = []
    live = dict(fragments)
    print(f"  {'event':<24} {'incremental':>22} {'memoised':>20} {'everything':>12}")
    for n, (provider, gone) in enumerate(((p, g) for p in chosen for g in (True, False)), 1):
        if gone:
            del live[provider]
        else:
            live[provider] = fragments[provider]
        request = request_of(n, live, relations, current)
        outcome, _ = timed_step(request, current, templates, None, repeat)
        with_memo, memo = timed_step(request, memoised, templates, memo, repeat)
        full_s = everything(request, templates)
        assert with_memo.planned.plan.flow == outcome.planned.plan.flow, "the memo changed a plan"
        rows.append(
            {
                "event": f"{provider} {'vanishes' if gone else 'comes back'}",
                **figures("incremental", outcome),
                **figures("memoised", with_memo),
                "everything_s": full_s,
            }
        )
        print(
            f"  {rows[-1]['event']:<24} {1e3 * outcome.seconds:8.1f} ms "
            f"({len(outcome.planned.replanned):3d} replanned) {1e3 * with_memo.seconds:8.1f} ms "
            f"({memo.hits:3d} hits) {1e3 * full_s:9.1f} ms"
        )
        current, memoised = outcome, with_memo
    added = RelationId(body(0, 2), tracker(0, 1), "6D")
    request = request_of(len(rows) + 1, live, [*relations, added], current)
    one, _ = timed_step(request, current, templates, None, repeat)
    one_memo, memo = timed_step(request, memoised, templates, memo, repeat)
    added_full_s = everything(request, templates)
    print(
        f"a query added among {len(relations)}: incremental {1e3 * one.seconds:.1f} ms "
        f"(replanning {1e3 * one.replanning_s:.1f} ms, {len(one.planned.replanned)} planned), "
        f"memoised {1e3 * one_memo.seconds:.1f} ms, everything {1e3 * added_full_s:.1f} ms"
    )
    workers = worker_events((current, memoised), memo, relations, live, templates, repeat)
    return {
        "shape": shape.__dict__,
        "providers": len(fragments),
        "edges": edges,
        "queries": len(relations),
        "unsolved": unsolved,
        "first_plan_s": first_s,
        **counts,
        "events": rows,
        "summary": summary(rows),
        "query_added": {
            **figures("incremental", one),
            **figures("memoised", one_memo),
            "everything_s": added_full_s,
        },
        "workers_appearing": workers,
        "memo": {"hits": memo.hits, "misses": memo.misses, "held": len(memo)},
    }


def figures(way: str, outcome: Outcome) -> dict[str, Any]:
    """A step's time, its replanning's, and the relations it planned."""
    return {
        f"{way}_s": outcome.seconds,
        f"{way}_replanning_s": outcome.replanning_s,
        f"{way}_replanned": len(outcome.planned.replanned),
    }


def worker_events(
    chains: tuple[Outcome, Outcome], memo: PlanMemo, relations, live, templates, repeat: int
) -> dict:
    """A worker nothing ran appears: one of a derivation within the margin of a relation's
    best (its relations are planned again), then one no derivation uses (none is); from the
    incremental and the memoised chain's last plan."""
    current, memoised = chains
    candidates = {c for part in current.planned.parts.values() for c in part.candidates}
    idle = candidates - current.request.running  # in no chosen derivation, if any is
    found: dict[str, Any] = {}
    for name, worker in (("candidate", min(idle or candidates)), ("unknown", "fusion-0")):
        running = current.request.running | {worker}
        request = Request(
            current.request.generation + 1, dict(live), frozenset(), frozenset(relations),
            running, True, frozenset({worker}),
        )  # fmt: skip
        outcome, _ = timed_step(request, current, templates, None, repeat)
        with_memo, _ = timed_step(request, memoised, templates, memo, repeat)
        found[name] = {**figures("incremental", outcome), **figures("memoised", with_memo)}
        print(
            f"a worker appears ({name}): {len(outcome.planned.replanned)} relations planned "
            f"again: incremental {1e3 * outcome.seconds:.1f} ms, memoised "
            f"{1e3 * with_memo.seconds:.1f} ms"
        )
    return found


def summary(rows: list[dict[str, Any]]) -> dict[str, dict[str, float]]:
    return {
        way: {
            "median_s": statistics.median(r[f"{way}_s"] for r in rows),
            "max_s": max(r[f"{way}_s"] for r in rows),
        }
        for way in ("incremental", "memoised", "everything")
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rooms", type=int, default=25)
    parser.add_argument("--events", type=int, default=10, help="provider events (even)")
    parser.add_argument(
        "--repeat", type=int, default=3, help="runs of each incremental step (the fastest kept)"
    )
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    shape = Building(
        rooms=args.rooms, bodies=2, redundant=1, cameras=2, features=7, shared_targets=True
    )
    result = run(shape, args.events, load_templates(), args.repeat)
    for way, times in result["summary"].items():
        print(
            f"{way:>12}: median {1e3 * times['median_s']:.1f} ms, "
            f"max {1e3 * times['max_s']:.1f} ms per provider event"
        )
    result["machine"] = f"{platform.machine()}, {platform.python_version()}"
    result["load_average"] = os.getloadavg()[0]
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
