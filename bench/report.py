"""How a bench hands over its figures: printed, and kept in ``bench/results/<name>.json``
(``CONTRIBUTING.md``, "Benchmarks"), where the docs that quote them point."""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any


def run_header() -> dict[str, Any]:
    """What every result file starts with: when (UTC), on what, and the load average then."""
    return {
        "date": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
        "machine": f"{platform.machine()}, Python {platform.python_version()}, "
        f"{os.cpu_count()} cores",
        "load_average_before": [round(x, 2) for x in os.getloadavg()],
    }


def write_results(path: Path, results: dict[str, Any]) -> None:
    """Print ``results`` as JSON and write them to ``path`` (its folder made if missing)."""
    text = json.dumps(results, indent=2)
    path.parent.mkdir(exist_ok=True)
    path.write_text(text + "\n")
    print(text)


def run_sizes(
    description: str,
    size: str,
    sizes: list[int],
    repeat: int,
    output: Path,
    measure: Callable[[int, int], dict[str, Any]],
    argv: list[str] | None = None,
) -> int:
    """A bench of one figure by problem size: ``--<size> N ...`` (default ``sizes``),
    ``--repeat`` and ``--output`` from ``argv``; ``measure(n, repeat)`` gives each size's row;
    the rows, the machine and its load average are written by :func:`write_results`."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument(f"--{size}", type=int, nargs="+", default=sizes, dest="sizes")
    parser.add_argument("--repeat", type=int, default=repeat, help="timed calls per size")
    parser.add_argument("--output", type=Path, default=output)
    args = parser.parse_args(argv)
    rows = [measure(n, args.repeat) for n in args.sizes]
    write_results(
        args.output,
        {
            "sizes": rows,
            "machine": f"{platform.machine()}, {platform.python_version()}",
            "load_average": os.getloadavg()[0],
        },
    )
    return 0
