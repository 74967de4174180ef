"""How a bench hands over its figures: printed, and kept in ``bench/results/<name>.json``
(``CONTRIBUTING.md``, "Benchmarks"), where the docs that quote them point."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


def write_results(path: Path, results: dict[str, Any]) -> None:
    """Print ``results`` as JSON and write them to ``path`` (its folder made if missing)."""
    text = json.dumps(results, indent=2)
    path.parent.mkdir(exist_ok=True)
    path.write_text(text + "\n")
    print(text)
