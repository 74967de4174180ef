"""What a sample's attachment costs: numbering a put and checking one at a reader
(``net.sequence``, ``net.address``).

Run: ``python -m bench.attachment_bench [--samples N] [--rounds R] [--compare-with DIR]
[--output FILE]``; prints the figures and writes them to ``bench/results/attachment.json``
(or ``FILE``). With ``--compare-with`` the same measurement runs, alternating round by round,
in a subprocess on the checkout in ``DIR`` (a worktree of an earlier commit), so both see the
same machine.

Per round: ``Numbering.next`` (the attachment of one put) timed over ``N`` calls, and a
reader's ``Numbers.take`` (``seen`` before the key's tag) over ``N`` attachments of one
publisher in order; the figures are the medians over rounds of the time per call.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

KEY = "ubitrack/demo/relation/C/A/6D/dynamic"


def measure(samples: int) -> dict[str, float]:
    """One round on the checkout this process imports: ns per call of each step."""
    from ubitrack_agent.net.sequence import Gaps, Numbering

    tagged = "key" in inspect.signature(Numbering).parameters  # the code with net.address
    numbering = Numbering(KEY) if tagged else Numbering()
    reader = Gaps().reader(KEY) if tagged else Gaps().reader()
    take = reader.take if tagged else reader.seen
    start = time.perf_counter()
    attachments = [numbering.next() for _ in range(samples)]
    put_s = time.perf_counter() - start
    start = time.perf_counter()
    for attachment in attachments:
        take(attachment)
    take_s = time.perf_counter() - start
    return {"next_ns": put_s / samples * 1e9, "take_ns": take_s / samples * 1e9}


def _round_in(checkout: Path, samples: int) -> dict[str, float]:
    """One round in a subprocess running this file on ``checkout``'s package."""
    environment = {**os.environ, "PYTHONPATH": str(checkout)}
    output = subprocess.run(
        [sys.executable, __file__, "--measure", str(samples)],
        cwd=checkout,
        env=environment,
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    return json.loads(output)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=200_000)
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--compare-with", type=Path, help="a checkout to measure alternately")
    parser.add_argument("--output", type=Path, default=Path("bench/results/attachment.json"))
    parser.add_argument("--measure", type=int, help=argparse.SUPPRESS)  # one round, in JSON
    args = parser.parse_args()
    if args.measure is not None:
        print(json.dumps(measure(args.measure)))
        return
    here = Path(__file__).resolve().parent.parent
    runs: dict[str, list[dict[str, float]]] = {"this": []}
    if args.compare_with is not None:
        runs["base"] = []
    for _ in range(args.rounds):
        runs["this"].append(_round_in(here, args.samples))
        if args.compare_with is not None:
            runs["base"].append(_round_in(args.compare_with.resolve(), args.samples))
    medians = {
        name: {step: statistics.median(r[step] for r in rounds) for step in rounds[0]}
        for name, rounds in runs.items()
    }
    for name, figures in medians.items():
        print(f"{name}: next {figures['next_ns']:.0f} ns, take {figures['take_ns']:.0f} ns")
    args.output.parent.mkdir(parents=True, exist_ok=True)
    report = {"samples": args.samples, "rounds": args.rounds, "medians": medians, "runs": runs}
    args.output.write_text(json.dumps(report, indent=1))
    print(f"written to {args.output}")


if __name__ == "__main__":
    main()
