"""The fusion after a gap in its inputs: how far off, and how honestly (issue 29, the chaos
runs' samples beyond 3 sigma).

Run: ``python -m bench.fusion_gap_bench [--floors 0.1,0.2,0.3,1] [--gaps-ms 20,40,60,80,100,150]
[--starts 20] [--output FILE]`` (about a minute per floor; writes
``bench/results/fusion_gap.json``).

The chaos runs' world offline (``tests/integration/chaos_faults.py``): two noise-free trackers
(``sim_trackers/exact_tracker.py``, 100 Hz each, 3 ms apart) each announcing 1 mm and 1 mrad on
every axis for its ``T -> HT`` and its static ``T -> WT`` (considered: a survey's error), and
the fusion (``services/components/fusion.py`` with ``templates/fusion.yaml``'s parameters but
``min_noise_scale``) of the two estimates of ``HT -> WT`` and of ``WT -> HT`` the planner makes
(each tracker's ``T -> HT`` inverted and concatenated with ``T -> WT``, or the other way round),
arriving 1-4 ms after their stamps. At each of ``--starts`` instants along the head's path
(every half second from 2 s) both trackers' samples of the next ``gap`` ms are lost (a stalled
machine, a full queue), and every output of the 100 ms before the gap to 300 ms after is judged
against the truth: the largest NEES and translation error per floor, gap and relation, over
the instants. The inputs are exact but claim 1 mm: the adaptive process noise falls to its
floor, and what the floor leaves the filter believing about the motion is what a gap tests.
The simulator's truth judges only.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from bench.synthetic import THREE_SIGMA_NEES
from tests.integration.chaos_faults import HT_WT, TRACKERS, WT_HT, judged
from ubitrack_agent.core import ErrorPose, Measurement, se3
from ubitrack_agent.core.poses import compose_poses, invert_pose, with_static_error
from ubitrack_agent.net.keys import RelationId
from ubitrack_agent.services.components.fusion import Fusion
from ubitrack_agent.sim_trackers.exact_tracker import tracker_pose, true_wt_ht

TEMPLATE = Path(__file__).parents[1] / "templates" / "fusion.yaml"
OUTPUT = Path(__file__).parent / "results" / "fusion_gap.json"
SIGMA = 1e-3
"""What each tracker announces (m and rad, every axis), as the chaos runs start them."""
RATE_HZ = 100.0
T0_NS = 1_700_000_000 * 10**9
BEFORE_S, AFTER_S = 0.1, 0.3
"""The outputs judged around a gap."""


def estimate(relation: RelationId, tracker: str, stamp_ns: int) -> Measurement:
    """A tracker's exact estimate of ``relation`` with its claimed covariance, as the flow
    makes it: ``T -> HT`` (white) and ``T -> WT`` (static), inverted and concatenated."""
    yaw, x = next((yaw, x) for frame, yaw, x in TRACKERS.values() if frame == tracker)
    q_wt, t_wt = tracker_pose(yaw, x)
    covariance = np.eye(6) * SIGMA**2
    to_head = ErrorPose(stamp_ns, *se3.compose(q_wt, t_wt, *true_wt_ht(stamp_ns)), covariance)
    to_world = with_static_error(ErrorPose(stamp_ns, q_wt, t_wt, covariance))
    if relation == HT_WT:
        return compose_poses(invert_pose(to_head), to_world)
    return compose_poses(invert_pose(to_world), to_head)


def worst_after_gap(
    relation: RelationId, parameters: dict[str, Any], start_s: float, gap_s: float
) -> tuple[float, float]:
    """The largest NEES and error (mm) of the fusion's outputs around a gap of ``gap_s`` from
    ``start_s``."""
    rng = np.random.default_rng(int(start_s * 1000))
    trackers = [frame for frame, _, _ in TRACKERS.values()]
    arrivals = []
    for k in range(int((start_s + AFTER_S) * RATE_HZ)):
        for i, tracker in enumerate(trackers):
            stamp = T0_NS + int(k * 1e9 / RATE_HZ) + i * 3_000_000
            if not start_s <= (stamp - T0_NS) * 1e-9 < start_s + gap_s:
                arrivals.append((stamp + int(rng.uniform(1e6, 4e6)), stamp, tracker))
    fusion = Fusion(parameters)
    worst = (0.0, 0.0)
    for _, stamp, tracker in sorted(arrivals):
        pushed = fusion.push("AB", estimate(relation, tracker, stamp), source=tracker)
        if pushed.outputs and (stamp - T0_NS) * 1e-9 >= start_s - BEFORE_S:
            judgement = judged(relation, pushed.outputs["fused"])
            worst = max(worst, (judgement.nees or 0.0, judgement.mm))
    return worst


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--floors", default="0.1,0.2,0.3,1", help="min_noise_scale values")
    parser.add_argument("--gaps-ms", default="20,40,60,80,100,150", help="gap lengths")
    parser.add_argument("--starts", type=int, default=20, help="instants along the path")
    parser.add_argument("--output", type=Path, default=OUTPUT)
    args = parser.parse_args(argv)
    template = yaml.safe_load(TEMPLATE.read_text())["parameters"]
    gaps = [float(g) / 1e3 for g in args.gaps_ms.split(",")]
    starts = [2.0 + 0.5 * i for i in range(args.starts)]
    rows = []
    print("| relation | floor | gap ms | largest NEES | largest error mm | beyond 3 sigma |")
    print("|---|---|---|---|---|---|")
    for relation in (HT_WT, WT_HT):
        for floor in (float(f) for f in args.floors.split(",")):
            parameters = {**template, "min_noise_scale": floor}
            for gap in gaps:
                worst = [worst_after_gap(relation, parameters, s, gap) for s in starts]
                row = {
                    "relation": str(relation),
                    "min_noise_scale": floor,
                    "gap_ms": gap * 1e3,
                    "nees_max": max(n for n, _ in worst),
                    "error_mm_max": max(mm for _, mm in worst),
                    "instants_beyond_3_sigma": sum(n > THREE_SIGMA_NEES for n, _ in worst),
                    "instants": len(worst),
                }
                rows.append(row)
                print(
                    f"| {relation} | {floor:g} | {gap * 1e3:.0f} | {row['nees_max']:.1f} | "
                    f"{row['error_mm_max']:.2f} | {row['instants_beyond_3_sigma']} of "
                    f"{len(worst)} |",
                    flush=True,
                )
    args.output.parent.mkdir(exist_ok=True)
    args.output.write_text(
        json.dumps(
            {
                "command": "python -m bench.fusion_gap_bench "
                f"--floors {args.floors} --gaps-ms {args.gaps_ms} --starts {args.starts}",
                "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                "rows": rows,
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
