"""The core layer stays free of zenoh and networkx (docs/architecture.md)."""

import ast
import subprocess
import sys
from pathlib import Path

CORE = Path(__file__).resolve().parents[2] / "ubitrack_agent" / "core"
FORBIDDEN = {"zenoh", "networkx", "subprocess", "multiprocessing"}


def imported_modules(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def test_core_sources_import_no_forbidden_module():
    files = sorted(CORE.glob("*.py"))
    assert files
    for path in files:
        assert not imported_modules(path) & FORBIDDEN, path.name


def test_importing_core_loads_neither_zenoh_nor_networkx():
    code = (
        "import sys, ubitrack_agent.core, ubitrack_agent.core.poses;"
        "print(sorted(m for m in ('zenoh', 'networkx') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
