"""Time to recovery per kind of event (issue 11), one event at a time.

Run: ``python -m bench.recovery_bench [--trials 5] [--seed 11] [--only TEXT] [--relations
A->B,...] [--cores N] [--output NAME]``. The live system of
``bench.churn_bench`` (an agent with its host manager, two noise-free trackers, the
applications ``WT->HT`` and ``HT->WT`` fused from both; real processes and zenoh on loopback),
steady before every trial (whole, warm pool full, every application fresh). Each trial is one
event of a kind, made by the chaos test's faults (``tests/integration/chaos_faults.py``):

* ``tracker SIGKILL``: a tracker (ART and IR in turn) killed and started again at once;
* ``container SIGKILL, warm pool``: the container (``ubitrack_agent.services.container``: one
process running
  several components) running the most components, killed; its host manager restores it with
  them (from its warm pool of 3) and the agent sends each its wiring (issue 28). Each container
  kill comes at least ``QUICK_RESTORE_S`` (10 s) after the one before: a container that dies
  sooner after its start more than three times in a row is not restored (a crash loop:
  ``ubitrack_agent.services.supervisor``), its components are started again by the agent instead,
  and the fourth of trials 2-3 s apart used to meet that guard (``restored`` never came);
* ``agent SIGKILL and restart``: the agent killed and started again at once (its workers keep
  running and are adopted);
* ``query open``: an application opens ``HT->ART``, which nothing else asks for (its first
  samples can come from the inversion of ``ART->HT`` that the ``HT->WT`` flow runs; a fusion of
  both trackers then takes over): the time to its first fresh, correct sample (and, as
  ``settled_s``, until it is fresh for good); it is closed after the trial;
* ``container SIGKILL, no pool``: as above, on a second system whose agent has
  ``--pool-size 0``, so the container starts in a new process (cold).

``--relations`` opens other applications (relations between ``WT``, ``HT``, ``ART`` and
``IR``); ``--cores N`` starts the host manager as a process of its own (the agent with
``--no-host``) running the components in ``N`` containers: ``--cores 1 --relations
'WT->HT,HT->WT,HT->ART,HT->IR'`` puts 12-15 components feeding four applications in one
container (issue 28's "a container with ten components"). A container kill also records the
restore's parts (``bench.restore_parts``: the host manager's report, the new container's
token, each component's start and readiness, and per application the time from the kill to its
first correct sample stamped after it) and which process took the group (a ready pool member,
one still starting, or a cold one); the summary gives, per application and for the worst
application of each kill, the median and largest time to that first sample, and the median of
each part.

Recovery is the time from the event until every application's data is fresh and correct again
for good: the end of its last outage after the event (``bench.availability.recovery``; fresh
and correct as in ``bench.churn_bench``: stamped within 0.25 s, within 3 mm of the truth), 0
when it never lapsed. The largest over the applications is the trial's figure. A trial ends
once the agent serves again every component it served before (``restored_s``: the killed
tracker's flows stopped and started again, the killed container's components restored and
rewired, or every component adopted by the restarted agent, as ``bench.agent_restart_bench``
measures it) and
every application has then been fresh for ``HOLD_S`` (at most ``TIMEOUT_S``). Printed per
trial (with the time, the machine's load average, what arrived: samples, those not correct,
the longest silence, each outage's start after the event and length), with the median,
minimum and maximum per kind, and written to ``bench/results/recovery.json`` (with ``--only``,
``recovery_<its first word>.json``).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import signal
import statistics
import time
from collections import Counter
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from bench.agent_restart_bench import agent_status, recovered, serving
from bench.availability import first_fresh, outages, recovery
from bench.churn_bench import APPLICATIONS, FRESH_S, Applications, machine, steady, system
from bench.restore_parts import RestoreWatch
from tests.integration.chaos_faults import (
    FLAPPING,
    POOL_SIZE,
    TRACKERS,
    TRUE_WITHIN_M,
    Chaos,
    host_status,
)
from ubitrack_agent.net.keys import RelationId
from ubitrack_agent.services.supervisor import QUICK_RESTORE_S

RESULTS = Path(__file__).with_name("results") / "recovery.json"
HOLD_S = 2.0
"""A trial ends once every application has been fresh this long."""
TIMEOUT_S = 60.0
POLL_S = 0.05
QUERY = FLAPPING
RESTORED_BY = ("containers_from_pool", "containers_from_starting_members", "containers_cold")
"""The host manager's counters of where a container started: which one grew is the trial's."""
"""The relation a new application opens (``HT->ART``: nothing else asks for it)."""


def observe(
    apps: Applications,
    relations: tuple[RelationId, ...],
    event: float,
    restored: Callable[[], bool] | None = None,
) -> dict[str, Any]:
    """Wait until ``restored`` (if given) has held and every one of ``relations`` has then been
    fresh for ``HOLD_S`` (at most ``TIMEOUT_S`` after ``event``, wall clock); the recovery of
    each (None: still down at the end), the largest, when ``restored`` first held, and what
    arrived."""
    held = None
    while (now := time.time()) - event < TIMEOUT_S:
        if restored is not None and held is None and restored():
            held = round(time.time() - event, 3)
        settled = restored is None or held is not None
        since = event + (held or 0.0)
        fresh = all(apps.fresh_since(relation, now - HOLD_S) for relation in relations)
        if settled and fresh and now - since >= HOLD_S:
            break
        time.sleep(POLL_S)
    end = time.time()
    each = {str(r): recovery(apps.intervals(r, event - 1.0), event, end) for r in relations}
    worst = None if None in each.values() else round(max(each.values()), 3)
    seen = {str(r): arrivals(apps, r, event, end) for r in relations}
    for relation in relations:  # when each outage began after the event, and how long it was
        gaps = outages(apps.intervals(relation, event - 1.0), event, end)
        seen[str(relation)]["outages"] = [[round(b - event, 2), round(e - b, 2)] for b, e in gaps]
    return {"recovery_s": worst, "applications": each, "restored_s": held, "arrivals": seen}


def back(chaos: Chaos, more: int, counter: str = "reconfigurations") -> Callable[[], bool]:
    """A condition, made before an event: the agent serves the components it serves now again
    (every one alive, nothing unsolved), its ``counter`` at least ``more`` higher (the event's
    reconfigurations, its stops and starts; or the components restored in place)."""
    now = chaos.setup.status() or {"components": {}, "counters": {}}
    before, base = set(now["components"]), now["counters"].get(counter, 0)

    def done() -> bool:
        status = agent_status(chaos.setup)
        return (
            serving(status)
            and set(status["components"]) == before
            and status["counters"].get(counter, 0) >= base + more
        )

    return done


def arrivals(apps: Applications, relation: RelationId, start: float, end: float) -> dict:
    """What arrived in ``[start, end)``: samples, those not correct, the longest silence (s)
    before each arrival, since ``start``."""
    noted = [(a, error) for a, _, error in apps.samples[relation] if start <= a < end]
    times = [start] + [a for a, _ in noted]
    return {
        "samples": len(noted),
        "incorrect": sum(error > TRUE_WITHIN_M for _, error in noted),
        "longest_silence_s": round(max(b - a for a, b in itertools.pairwise(times)), 3)
        if noted
        else None,
    }


def tracker_kill(chaos: Chaos, apps: Applications, trial: int) -> dict[str, Any]:
    name = sorted(TRACKERS)[trial % len(TRACKERS)]
    restored = back(chaos, 2)  # its flows stopped, started again
    event = time.time()
    chaos.kill_tracker(name, signal.SIGKILL).action()  # started again at once
    return observe(apps, apps.ids, event, restored)


_CONTAINER_KILLED_AT = [-QUICK_RESTORE_S]
"""When the latest container kill was (monotonic)."""


def container_kill(chaos: Chaos, apps: Applications, trial: int) -> dict[str, Any]:
    """The container running the most components (ties: the lower pid) killed; restored when
    the agent has been told of every one's restoration and each is alive again. With the
    restore's parts (``bench.restore_parts``) and the process that took the group (a ready pool
    member, one still starting, or a cold one: the host manager's counters)."""
    since = time.monotonic() - _CONTAINER_KILLED_AT[0]
    if since < QUICK_RESTORE_S:  # not a crash loop: the guard would not restore it
        time.sleep(QUICK_RESTORE_S - since)
    host = host_status(chaos.setup) or {"instances": {}, "name": "", "counters": {}}
    members = Counter(entry["pid"] for entry in host["instances"].values())
    pid, count = min(members.items(), key=lambda item: (-item[1], item[0]))
    restored = back(chaos, count, counter="restored")
    watch = RestoreWatch(chaos.setup.session, chaos.setup.keys, host["name"]).open()
    try:
        event = time.time()
        os.kill(pid, signal.SIGKILL)
        _CONTAINER_KILLED_AT[0] = time.monotonic()
        chaos.log.append(f"container {pid} ({count} components) SIGKILL")
        result = observe(apps, apps.ids, event, restored) | {"components": count}
        parts = watch.parts(event, pid, apps)
    finally:
        watch.close()
    later = host_status(chaos.setup) or {"counters": {}}
    parts |= host_parts(later.get("last_restore"), event)
    taken = {k: later["counters"].get(k, 0) - host["counters"].get(k, 0) for k in RESTORED_BY}
    return result | {"restore": parts, "restored_by": [k for k, v in taken.items() if v > 0]}


def host_parts(restore: dict[str, Any] | None, event: float) -> dict[str, float | None]:
    """The host manager's own stamps of its latest restore (its status's ``last_restore``,
    absent before it had them): when it noticed the death, when it gave the group to a process
    (or spawned one for it), in seconds after ``event``; None where unknown."""
    if not restore or restore["noticed_ns"] * 1e-9 < event:
        return {"noticed_s": None, "group_given_s": None}
    return {
        "noticed_s": round(restore["noticed_ns"] * 1e-9 - event, 4),
        "group_given_s": round(restore["started_ns"] * 1e-9 - event, 4),
    }


def agent_kill(chaos: Chaos, apps: Applications, trial: int) -> dict[str, Any]:
    before = set((chaos.setup.status() or {"components": {}})["components"])
    event = time.time()
    chaos.kill_agent(signal.SIGKILL)
    return observe(apps, apps.ids, event, lambda: recovered(agent_status(chaos.setup), before))


def query_open(chaos: Chaos, apps: Applications, trial: int) -> dict[str, Any]:
    """Recovery here is the time to the first fresh, correct sample; the time until the data
    is fresh for good is ``settled_s``."""
    event = time.time()
    relation = apps.open(QUERY, f"probe{trial}")
    try:
        result = observe(apps, (QUERY,), event)
    finally:
        relation.close()
    first = first_fresh(apps.intervals(QUERY, event + FRESH_S), event)  # samples after event
    settled = result["recovery_s"]
    return result | {"recovery_s": None if first is None else round(first, 3), "settled_s": settled}


Trial = Callable[[Chaos, Applications, int], dict[str, Any]]
WARM: dict[str, Trial] = {
    "tracker SIGKILL": tracker_kill,
    "container SIGKILL, warm pool": container_kill,
    "agent SIGKILL and restart": agent_kill,
    "query open": query_open,
}
COLD: dict[str, Trial] = {"container SIGKILL, no pool": container_kill}


def trials(chaos: Chaos, apps: Applications, kinds: dict[str, Trial], count: int) -> list[dict]:
    """``count`` trials of each kind, each from a steady system."""
    rows = []
    for kind, trial in kinds.items():
        for index in range(count):
            problem = steady(chaos, apps)
            if problem is not None:
                raise RuntimeError(f"not steady before {kind} trial {index + 1}: {problem}")
            logged = len(chaos.log)
            at = datetime.now(UTC).strftime("%H:%M:%S")
            row = {"kind": kind, "trial": index + 1, "at": at, "load_1min": os.getloadavg()[0]}
            row |= trial(chaos, apps, index)
            row["event"] = chaos.log[-1] if len(chaos.log) > logged else "query opened"
            rows.append(row)
            print(json.dumps(row), flush=True)
    return rows


def summary(rows: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Median, minimum and maximum recovery per kind (and of ``restored_s``, where measured)."""
    kinds: dict[str, dict[str, Any]] = {}
    for kind in dict.fromkeys(row["kind"] for row in rows):
        mine = [row for row in rows if row["kind"] == kind]
        done = [row["recovery_s"] for row in mine if row["recovery_s"] is not None]
        figures: dict[str, Any] = {"trials": len(mine), "not_recovered": len(mine) - len(done)}
        figures |= spread("recovery", done)
        figures |= spread("restored", [r["restored_s"] for r in mine if r["restored_s"]])
        if any("restore" in row for row in mine):
            figures |= restore_summary([row["restore"] for row in mine if "restore" in row])
        kinds[kind] = figures
    return kinds


def restore_summary(restores: list[dict[str, Any]]) -> dict[str, Any]:
    """Over the container kills: per application, the time to its first sample again (median,
    maximum; ``None`` counted as never), the worst application's per kill, and the median of
    each part of the restore (``bench.restore_parts``)."""
    names = list(restores[0]["applications_back_s"])
    per_application = {}
    for name in names:
        times = [r["applications_back_s"][name] for r in restores]
        done = [t for t in times if t is not None]
        per_application[name] = spread("back", done) | {"never": len(times) - len(done)}
    worst = [
        max(r["applications_back_s"].values())
        for r in restores
        if None not in r["applications_back_s"].values()
    ]
    parts: dict[str, Any] = {}
    for part in ("noticed_s", "group_given_s", "old_tokens_gone_s", "reported_s", "container_up_s"):
        parts[part] = median_of([r.get(part) for r in restores])
    for part in ("components_created_s", "components_ready_s", "components_up_s"):
        pairs = [r[part] for r in restores if r[part] is not None]
        parts[f"{part}_first_last"] = [
            median_of([p[0] for p in pairs]),
            median_of([p[1] for p in pairs]),
        ]
    return {
        "applications_back": per_application,
        **spread("worst_application_back", worst),
        "restore_parts_median_s": parts,
    }


def median_of(values: list[float | None]) -> float | None:
    known = [v for v in values if v is not None]
    return round(statistics.median(known), 4) if known else None


def spread(name: str, values: list[float]) -> dict[str, float]:
    if not values:
        return {}
    return {
        f"{name}_median_s": round(statistics.median(values), 3),
        f"{name}_min_s": min(values),
        f"{name}_max_s": max(values),
    }


def parse_relation(text: str) -> RelationId:
    """``WT->HT`` as the 6D relation from WT to HT."""
    source, arrow, target = text.strip().partition("->")
    if not arrow or not source or not target:
        raise argparse.ArgumentTypeError(f"{text!r}: expected SOURCE->TARGET")
    return RelationId(source, target, "6D")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.recovery_bench", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--trials", type=int, default=5, help="trials per kind (default 5)")
    parser.add_argument("--seed", type=int, default=11, help="seed of the faults (default 11)")
    parser.add_argument(
        "--only", default="", help="run only the kinds whose name holds this text (default: all)"
    )
    parser.add_argument(
        "--output",
        default="",
        help="the results file's name in bench/results, without .json (default: recovery, or "
        "recovery_<first word of --only>)",
    )
    parser.add_argument(
        "--relations",
        default="",
        help="the applications' relations, comma-separated, e.g. WT->HT,HT->WT,HT->ART,HT->IR "
        "(between WT, HT, ART and IR; default: WT->HT,HT->WT)",
    )
    parser.add_argument(
        "--cores",
        type=int,
        default=None,
        help="the host manager runs the components in this many containers (its own process, "
        "`ubitrack host --cores`; default: the agent's own host manager, one per CPU core)",
    )
    args = parser.parse_args(argv)
    relations = tuple(parse_relation(text) for text in args.relations.split(",") if text)
    relations = relations or APPLICATIONS
    warm = {kind: trial for kind, trial in WARM.items() if args.only in kind}
    cold = {kind: trial for kind, trial in COLD.items() if args.only in kind}
    rows: list[dict[str, Any]] = []
    if warm:
        with system(POOL_SIZE, args.seed, relations, args.cores) as (chaos, apps):
            rows += trials(chaos, apps, warm, args.trials)
    if cold:
        with system(0, args.seed, relations, args.cores) as (chaos, apps):
            rows += trials(chaos, apps, cold, args.trials)
    only = f" --only '{args.only}'" if args.only else ""
    only += f" --relations '{args.relations}'" if args.relations else ""
    only += f" --cores {args.cores}" if args.cores is not None else ""
    results = {
        "command": f"python -m bench.recovery_bench --trials {args.trials} --seed {args.seed}"
        + only,
        "date": datetime.now(UTC).strftime("%Y-%m-%d"),
        "machine": machine(),
        "summary": summary(rows),
        "trials": rows,
    }
    written = RESULTS.with_stem(args.output) if args.output else RESULTS
    if args.only and not args.output:
        written = RESULTS.with_stem(f"recovery_{args.only.split()[0]}")
    written.parent.mkdir(exist_ok=True)
    written.write_text(json.dumps(results, indent=2) + "\n")
    print(json.dumps(results["summary"], indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
