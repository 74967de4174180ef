"""Every benchmark in ``bench/`` is run by ``make bench`` and described in CONTRIBUTING.md, so
the figures in ``docs/performance.md`` can be reproduced from the list a newcomer reads."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def benchmarks() -> set[str]:
    """``bench/*_bench.py`` and the worker start-up measurement (helpers such as a relay or a
    recording are run by the benchmarks, not on their own)."""
    return {path.stem for path in (ROOT / "bench").glob("*_bench.py")} | {"worker_start"}


def test_make_bench_runs_every_benchmark():
    text = (ROOT / "Makefile").read_text()
    listed = re.search(r"^bench:.*?for name in (.*?); do", text, re.S | re.M)
    assert listed is not None
    assert benchmarks() - set(listed.group(1).replace("\\", " ").split()) == set()


def test_contributing_describes_every_benchmark():
    text = (ROOT / "CONTRIBUTING.md").read_text()
    assert {name for name in benchmarks() if f"python -m bench.{name}" not in text} == set()
