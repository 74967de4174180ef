"""Availability under churn (issue 11): the fraction of time each application receives fresh,
correct data while faults come at a given rate.

Run: ``python -m bench.churn_bench [--rates 0,0.1,0.3,1,2] [--seconds 50] [--seed 11]``.
Everything on loopback with real zenoh and real processes, as the chaos test
(``tests/integration/test_chaos.py``): an agent with its host manager (warm pool of 3), two
noise-free trackers (``ubitrack_agent.sim_trackers.exact_tracker``, 100 Hz each) and two
applications, ``WT->HT`` and ``HT->WT``, each fused from both trackers (ten workers).

For each rate (events per second) the bench injects, for ``--seconds``, faults at the times of
a Poisson process of that rate, each of a kind drawn with equal odds: the chaos test's faults
(``tests/integration/chaos_faults.py``: a tracker killed, SIGKILL or SIGTERM, and started again
after 0-1.5 s; a worker killed; the agent killed and started again at once; a query opened and
closed within 0.05-0.4 s). Faults run one at a time: one that blocks (an agent's clean stop)
delays the next, so the rate reached is reported too. Each rate has its own seeded random
stream (``--seed`` and the rate), so a run repeats the same faults in the same order, up to
the first one skipped (a worker kill while no agent answers draws less).

Measured for each application over each window: the fraction of time it holds fresh, correct
data (``bench/availability.py``): *fresh*, a sample stamped within the last ``FRESH_S``
(0.25 s); *correct*, within ``TRUE_WITHIN_M`` (3 mm, the largest element difference of the
pose matrices) of the trackers' known truth at its stamp. Also its longest outage (and when
each outage over 0.5 s began, in s after the window's start), the samples that were not
correct, each fault done with its time, the faults by kind, the machine's load average (1 min)
at the start and end of the window (others share it), and after each window the time until
the system is whole again (the chaos test's check: one process per wanted component, nothing
unwanted, no leaked pool worker) with the warm pool full. Printed, and written to
``bench/results/churn.json``.
"""

from __future__ import annotations

import argparse
import bisect
import contextlib
import heapq
import itertools
import json
import os
import platform
import random
import time
from collections import Counter
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from bench.availability import availability, fresh_intervals, longest_outage, outages
from tests.integration.chaos_faults import (
    HT_WT,
    POOL_SIZE,
    TRUE_WITHIN_M,
    WT_HT,
    Chaos,
    Judged,
    host_status,
    judged,
    truth_error,
    whole,
)
from tests.integration.conftest import end_groups
from tests.integration.test_agent import Setup, opened
from ubitrack_agent.core import Measurement
from ubitrack_agent.io.application import Relation
from ubitrack_agent.net.keys import RelationId

RESULTS = Path(__file__).with_name("results") / "churn.json"
FRESH_S = 0.25
"""A sample is fresh while it is stamped less than this long ago."""
APPLICATIONS = (WT_HT, HT_WT)
STEADY_S = 120.0
"""How long the system may take to be whole again, pool full, after a window."""


class Applications:
    """Applications listening to relations; each sample's arrival, stamp (wall clock, s) and
    error against truth noted as it arrives, and its judgement (``chaos_faults.judged``:
    errors in mm and degrees, NEES against its own covariance)."""

    def __init__(self, setup: Setup, relations: tuple[RelationId, ...]) -> None:
        self.setup = setup
        self.ids = relations
        """The relations the applications opened at the start (not those of :meth:`open`)."""
        self.samples: dict[RelationId, list[tuple[float, float, float]]] = {}
        self.judgements: dict[RelationId, list[tuple[float, Judged]]] = {}
        self.wrong: dict[RelationId, dict[float, Measurement]] = {}
        """The wrong samples themselves (``Judged.wrong``), by arrival: to look into."""
        self.relations = [self.open(relation, f"app{i}") for i, relation in enumerate(relations)]

    def open(self, relation: RelationId, application: str) -> Relation:
        """One more application of ``relation``, noted like the others."""
        noted = self.samples.setdefault(relation, [])
        judgements = self.judgements.setdefault(relation, [])
        wrong = self.wrong.setdefault(relation, {})

        def note(sample: Measurement) -> None:
            arrived = time.time()
            noted.append((arrived, sample.timestamp_ns * 1e-9, truth_error(relation, sample)))
            judgement = judged(relation, sample)
            judgements.append((arrived, judgement))
            if judgement.wrong:
                wrong[arrived] = sample

        return Relation(
            self.setup.session, self.setup.keys, relation, application=application, callback=note
        )

    def intervals(self, relation: RelationId, since: float = 0.0) -> list[tuple[float, float]]:
        """When ``relation`` had fresh, correct data (``bench.availability.fresh_intervals``),
        from ``since`` on (wall clock, s)."""
        noted = self.samples[relation]
        first = bisect.bisect_left(noted, since - FRESH_S, key=lambda sample: sample[0])
        correct = [(a, s) for a, s, error in noted[first:] if error <= TRUE_WITHIN_M]
        return fresh_intervals(correct, FRESH_S)

    def fresh_since(self, relation: RelationId, since: float) -> bool:
        """Whether ``relation`` has had fresh, correct data from ``since`` until now."""
        now = time.time()
        return any(b <= since and e > now for b, e in self.intervals(relation, since))

    def incorrect(self, relation: RelationId, start: float, end: float) -> int:
        """Samples arrived in ``[start, end)`` beyond the tolerance."""
        return sum(
            start <= a < end and error > TRUE_WITHIN_M for a, _, error in self.samples[relation]
        )

    def close(self) -> None:
        for relation in self.relations:
            relation.close()


def steady(chaos: Chaos, applications: Applications, timeout: float = STEADY_S) -> str | None:
    """Wait until the system is whole (``chaos_faults.whole``), the warm pool full and every
    application fresh for the last second; None then, else what was last wrong."""
    deadline = time.monotonic() + timeout
    while True:
        problem = whole(chaos.setup, chaos.pool_size)
        if problem is None:
            host = host_status(chaos.setup) or {"pool_ready": -1}
            if host["pool_ready"] < chaos.pool_size:
                problem = f"pool {host['pool_ready']} of {chaos.pool_size}"
        if problem is None:
            since = time.time() - 1.0
            stale = [str(r) for r in applications.ids if not applications.fresh_since(r, since)]
            problem = f"not fresh: {stale}" if stale else None
        if problem is None or time.monotonic() > deadline:
            return problem
        time.sleep(0.5)


def event_offsets(rate: float, seconds: float, rng: random.Random) -> list[float]:
    """The times in ``[0, seconds)`` of a Poisson process of ``rate`` per second."""
    offsets: list[float] = []
    at = rng.expovariate(rate) if rate > 0 else seconds
    while at < seconds:
        offsets.append(at)
        at += rng.expovariate(rate)
    return offsets


def kind_of(entry: str) -> str:
    """A fault's kind from its log entry: ``tracker ir SIGKILL`` -> ``tracker SIGKILL``."""
    words = entry.split()
    return f"{words[0]} {words[-1]}"


class Followups:
    """Follow-ups of faults (restarts, closes), each run when due."""

    def __init__(self) -> None:
        self.due: list[tuple[float, int, Callable[[], None]]] = []
        self.order = itertools.count()

    def add(self, delay: float, action: Callable[[], None]) -> None:
        heapq.heappush(self.due, (time.monotonic() + delay, next(self.order), action))

    def run_until(self, until: float) -> None:
        """Run those due before ``until`` (monotonic), each at its time; return at ``until``
        (at once after the last one if ``until`` is infinite)."""
        while self.due and self.due[0][0] < until:
            at, _, action = heapq.heappop(self.due)
            time.sleep(max(0.0, at - time.monotonic()))
            action()
        if until != float("inf"):
            time.sleep(max(0.0, until - time.monotonic()))


def churn(chaos: Chaos, apps: Applications, rate: float, seconds: float, seed: int) -> dict:
    """One window of ``seconds`` with faults at ``rate`` per second; its figures."""
    chaos.rng = random.Random(f"{seed}/{rate:g}")
    kinds = {fault.__name__: fault for fault in chaos.kinds()}
    offsets = event_offsets(rate, seconds, chaos.rng)
    followups = Followups()
    done: Counter = Counter()
    skipped: Counter = Counter()
    timeline: list[list] = []
    began, start, load = time.monotonic(), time.time(), os.getloadavg()[0]
    for offset in offsets:
        followups.run_until(began + offset)
        if time.monotonic() >= began + seconds:
            break  # faults that blocked pushed this one past the window
        name = chaos.rng.choice(sorted(kinds))
        logged, at = len(chaos.log), round(time.time() - start, 2)
        follow = kinds[name]()
        if len(chaos.log) > logged:
            done[kind_of(chaos.log[-1])] += 1
            timeline.append([at, chaos.log[-1]])
        else:
            skipped[name] += 1
        if follow is not None:
            followups.add(follow.delay, follow.action)
    followups.run_until(began + seconds)
    end = time.time()
    followups.run_until(float("inf"))
    settle_began = time.monotonic()
    problem = steady(chaos, apps)
    applications = {}
    for relation in APPLICATIONS:
        intervals = apps.intervals(relation)
        applications[str(relation)] = {
            "availability": round(availability(intervals, start, end), 4),
            "longest_outage_s": round(longest_outage(intervals, start, end), 3),
            "incorrect_samples": apps.incorrect(relation, start, end),
            "samples": sum(start <= a < end for a, _, _ in apps.samples[relation]),
            "outages_over_half_s": [
                [round(b - start, 2), round(e - b, 2)]
                for b, e in outages(intervals, start, end)
                if e - b > 0.5
            ],
        }
    return {
        "rate": rate,
        "seconds": round(end - start, 2),
        "events": sum(done.values()),
        "events_per_s": round(sum(done.values()) / (end - start), 3),
        "events_by_kind": dict(sorted(done.items())),
        "skipped_by_kind": dict(sorted(skipped.items())),
        "applications": applications,
        "faults": timeline,
        "load_1min": [round(load, 1), round(os.getloadavg()[0], 1)],
        "steady_after_s": round(time.monotonic() - settle_began, 1),
        "steady_problem": problem,
    }


@contextlib.contextmanager
def system(
    pool_size: int,
    seed: int,
    relations: tuple[RelationId, ...] = APPLICATIONS,
    cores: int | None = None,
) -> Iterator[tuple[Chaos, Applications]]:
    """The live system, steady, with an application of each of ``relations`` (``cores``: the
    host manager's containers, :class:`Chaos`); every process ended afterwards."""
    processes: list = []
    try:
        with contextlib.contextmanager(opened)(processes) as setup:
            chaos = Chaos(setup, random.Random(seed), pool_size, cores)
            apps = Applications(setup, relations)
            problem = steady(chaos, apps)
            if problem is not None:
                raise RuntimeError(f"the system never became steady: {problem}")
            try:
                yield chaos, apps
            finally:
                apps.close()
    finally:
        end_groups(processes)


def run(rates: list[float], seconds: float, seed: int) -> list[dict[str, Any]]:
    rows = []
    with system(POOL_SIZE, seed) as (chaos, apps):
        for rate in rates:
            row = churn(chaos, apps, rate, seconds, seed)
            rows.append(row)
            print(json.dumps(row), flush=True)
    return rows


def table(rows: list[dict[str, Any]]) -> str:
    """The figures as Markdown tables: availability per application, then faults by kind."""
    names = list(rows[0]["applications"])
    head = ["events/s asked", "reached", "events", "load (1 min)"]
    head += [f"{name} available" for name in names] + [f"{name} longest outage" for name in names]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        apps = row["applications"]
        cells = [f"{row['rate']:g}", f"{row['events_per_s']:.2f}", str(row["events"])]
        cells.append("-".join(f"{load:g}" for load in row["load_1min"]))
        cells += [f"{100 * apps[n]['availability']:.1f} %" for n in names]
        cells += [f"{apps[n]['longest_outage_s']:.2f} s" for n in names]
        lines.append("| " + " | ".join(cells) + " |")
    kinds = sorted({kind for row in rows for kind in row["events_by_kind"]})
    lines += ["", "| events/s asked | " + " | ".join(kinds) + " | skipped |"]
    lines.append("|" + "---|" * (len(kinds) + 2))
    for row in rows:
        cells = [f"{row['rate']:g}"] + [str(row["events_by_kind"].get(k, 0)) for k in kinds]
        cells.append(str(sum(row["skipped_by_kind"].values())))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def machine() -> str:
    return f"{platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.churn_bench", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--rates", default="0,0.1,0.3,1,2", help="events per second, by commas")
    parser.add_argument("--seconds", type=float, default=50.0, help="window per rate (50)")
    parser.add_argument("--seed", type=int, default=11, help="fault seed (default 11)")
    args = parser.parse_args(argv)
    rates = [float(rate) for rate in args.rates.split(",")]
    rows = run(rates, args.seconds, args.seed)
    results = {
        "command": f"python -m bench.churn_bench --rates {args.rates} "
        f"--seconds {args.seconds:g} --seed {args.seed}",
        "date": datetime.now(UTC).strftime("%Y-%m-%d"),
        "machine": machine(),
        "fresh_s": FRESH_S,
        "correct_within_m": TRUE_WITHIN_M,
        "rows": rows,
    }
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=2) + "\n")
    print(table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
