"""What turning a changed plan into worker specifications costs, by the plan's size
(``agent.materialise.component_specs``: one specification per component, O(components +
bindings + relations); issue 28, "the fold's special code is gone").

The plans are those of ``bench.agent_replan_bench``'s generated building (four queries per
room, every query planned), for several numbers of rooms; for each, the median of
``--repeat`` timed calls (CPU time of this process, ``time.process_time``: the machine is
shared, and wall-clock time grows with the other jobs' load), and the time per
specification: flat if the growth is linear. Run::

    .venv/bin/python -m bench.materialise_bench       # writes bench/results/materialise.json
    .venv/bin/python -m bench.materialise_bench --rooms 5 10

Before the fold was retired, a changed plan took component_specs plus the fold, whose search
for each candidate's producer and readers made it O(components^2): 2.7, 3.3, 14.6 and 41.0 ms
of CPU for 5, 10, 25 and 50 rooms, against 0.9, 1.9, 8.8 and 10.8 ms for component_specs
alone, measured side by side (2026-11-27, ``docs/performance.md``).
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path
from typing import Any

from bench.agent_replan_bench import KEYS, fragments_of, queries_of
from bench.building import Building
from bench.report import run_sizes
from ubitrack_agent.agent.announcements import build_srg
from ubitrack_agent.agent.flows import plan_relations
from ubitrack_agent.agent.materialise import component_specs
from ubitrack_agent.graph.templates import load_templates

RESULTS = Path(__file__).with_name("results") / "materialise.json"


def measure(rooms: int, templates: Any, repeat: int) -> dict[str, Any]:
    """The specifications of the building's whole plan, timed ``repeat`` times."""
    shape = Building(rooms=rooms, bodies=2, redundant=1, cameras=2, features=7, shared_targets=True)
    srg = build_srg(fragments_of(shape))
    plan = plan_relations(srg, templates, frozenset(queries_of(shape)), frozenset())
    times = []
    for _ in range(repeat):
        started = time.process_time()
        specs = component_specs(plan.flow, srg, KEYS, plan.relations)
        times.append(time.process_time() - started)
    median = statistics.median(times)
    bindings = sum(len(spec.inputs) for spec in specs.values())
    row = {
        "rooms": rooms,
        "components": len(plan.flow.components),
        "specifications": len(specs),
        "bindings": bindings,
        "median_ms": round(1e3 * median, 3),
        "us_per_specification": round(1e6 * median / len(specs), 2),
    }
    print(
        f"{rooms:3d} rooms: {len(specs):4d} specifications, {bindings:5d} bindings: "
        f"{row['median_ms']:7.2f} ms ({row['us_per_specification']:.1f} us each)",
        flush=True,
    )
    return row


def main(argv: list[str] | None = None) -> int:
    templates = load_templates()
    return run_sizes(
        __doc__.split("\n\n")[0],
        "rooms",
        [5, 10, 25, 50],
        7,
        RESULTS,
        lambda rooms, repeat: measure(rooms, templates, repeat),
        argv,
    )


if __name__ == "__main__":
    raise SystemExit(main())
