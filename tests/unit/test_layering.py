"""Each folder is one layer and imports only the layers below it (docs/architecture.md).

Every module of the product is read with ``ast`` (imports inside functions count too, so a
lazy import cannot hide a back-reference). A module belongs to the layer of the longest
package prefix in :data:`LAYERS`; it may import its own layer and those its entry lists, and
none of the third-party modules its entry forbids. The checker is tested on deliberately
broken trees, so it is known to fail when a layer reaches upwards.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PRODUCT = ("ubitrack_agent", "services", "sim_trackers", "templates")
"""Top-level folders that ship; tests and benchmarks may import anything."""
MAPPED = ("services", "sim_trackers", "templates")
"""Folders that install as subpackages of ``ubitrack_agent`` (``setup.py``): a module's name
there starts ``ubitrack_agent.``, and an import of the bare folder name is in no layer."""


@dataclass(frozen=True)
class Layer:
    allowed: frozenset[str]
    """Project layers this one may import (besides itself)."""
    forbidden: frozenset[str] = frozenset()
    """Third-party or standard modules it must not import."""


def _layer(*allowed: str, forbidden: tuple[str, ...] = ()) -> Layer:
    return Layer(frozenset(allowed), frozenset(forbidden))


CORE, GRAPH, NET, IO = (f"ubitrack_agent.{name}" for name in ("core", "graph", "net", "io"))
AGENT, CAMERA = "ubitrack_agent.agent", f"{IO}.camera"
SERVICES, SIMULATORS, TEMPLATES = (f"ubitrack_agent.{name}" for name in MAPPED)
EVERYTHING = (CORE, GRAPH, NET, IO, CAMERA, AGENT, SERVICES, SIMULATORS, TEMPLATES)
NO_PROCESSES = ("subprocess", "multiprocessing")
LAYERS: dict[str, Layer] = {
    # Bottom to top.
    "ubitrack_agent": _layer(),  # the package itself: its version only
    TEMPLATES: _layer(),  # data
    CORE: _layer(forbidden=("zenoh", "networkx", "cv2", *NO_PROCESSES)),
    GRAPH: _layer(CORE, forbidden=("zenoh", "cv2", *NO_PROCESSES)),
    NET: _layer(CORE, forbidden=("networkx", "cv2", *NO_PROCESSES)),
    IO: _layer(CORE, NET, forbidden=("networkx", "cv2")),
    CAMERA: _layer(CORE, NET, IO, forbidden=("networkx",)),  # the one io package with OpenCV
    AGENT: _layer(CORE, GRAPH, NET, forbidden=("cv2", "scipy")),
    SERVICES: _layer(CORE, NET, forbidden=("networkx",)),
    SIMULATORS: _layer(CORE, NET, IO, forbidden=("networkx",)),
    "ubitrack_agent.cli": _layer(*EVERYTHING, "ubitrack_agent.commands"),
    "ubitrack_agent.commands": _layer(*EVERYTHING, "ubitrack_agent.cli"),
}


def module_name(root: Path, path: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[0] in MAPPED:
        parts.insert(0, "ubitrack_agent")
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def layer_of(module: str) -> str | None:
    """The longest entry of :data:`LAYERS` that is ``module`` or a package containing it (the
    root package's entry covers its ``__init__`` only, so a new module there has no layer)."""
    candidates = [
        name
        for name in LAYERS
        if module == name or (module.startswith(name + ".") and name != "ubitrack_agent")
    ]
    return max(candidates, key=len, default=None)


def imported_layer(name: str) -> str | None:
    """The layer of an imported name: a module's, or for ``from package import symbol`` the
    package's."""
    return layer_of(name) or layer_of(name.rpartition(".")[0])


def imports(path: Path, module: str) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in ``path``; relative ones resolved."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            # ``from pkg import module`` imports pkg.module: check the deeper name.
            found += [(node.lineno, f"{name}.{alias.name}") for alias in node.names]
    return found


def violations(root: Path) -> list[str]:
    """Every import in the product under ``root`` that breaks :data:`LAYERS`."""
    problems = []
    files = [path for top in PRODUCT for path in sorted((root / top).rglob("*.py"))]
    for path in files:
        module = module_name(root, path)
        own = layer_of(module)
        if own is None:
            problems.append(f"{module}: in no layer; add its package to LAYERS")
            continue
        rule = LAYERS[own]
        for line, name in imports(path, module):
            target = imported_layer(name)
            top = name.split(".")[0]
            where = f"{path.relative_to(root)}:{line}"
            if target is None and top in {p.split(".")[0] for p in PRODUCT}:
                problems.append(f"{where}: {module} imports {name}, which is in no layer")
            elif target not in (None, own, "ubitrack_agent") and target not in rule.allowed:
                problems.append(f"{where}: {own} may not import {target} ({name})")
            elif target is None and top in rule.forbidden:
                problems.append(f"{where}: {own} may not import {top}")
    return problems


def test_the_product_keeps_its_layers():
    assert not violations(ROOT), "\n".join(violations(ROOT))


def test_every_package_of_the_product_has_a_layer():
    packages = {module_name(ROOT, p) for top in PRODUCT for p in (ROOT / top).rglob("*.py")}
    assert packages and all(layer_of(name) is not None for name in packages)


def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        path = tmp_path / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    for top in PRODUCT:
        (tmp_path / top).mkdir(exist_ok=True)
    return tmp_path


@pytest.mark.parametrize(
    "files, expected",
    [
        # A lower layer reaching up, in each import form.
        (
            {"ubitrack_agent/core/bad.py": "from ubitrack_agent.net import keys\n"},
            "ubitrack_agent.core may not import ubitrack_agent.net",
        ),
        (
            {"ubitrack_agent/graph/bad.py": "import ubitrack_agent.agent.runtime\n"},
            "ubitrack_agent.graph may not import ubitrack_agent.agent",
        ),
        (
            {"ubitrack_agent/net/bad.py": "from ..graph import srg\n"},
            "ubitrack_agent.net may not import ubitrack_agent.graph",
        ),
        (
            {
                "ubitrack_agent/agent/bad.py": (
                    "def f():\n    from ubitrack_agent.services.registry import lookup\n"
                )
            },
            "ubitrack_agent.agent may not import ubitrack_agent.services",
        ),
        (
            {"services/bad.py": "from ubitrack_agent import cli\n"},
            "ubitrack_agent.services may not import ubitrack_agent.cli",
        ),
        (
            {"sim_trackers/bad.py": "from ubitrack_agent.agent import runtime\n"},
            "ubitrack_agent.sim_trackers may not import ubitrack_agent.agent",
        ),
        (
            {"ubitrack_agent/io/bad.py": "import ubitrack_agent.sim_trackers.world\n"},
            "ubitrack_agent.io may not import ubitrack_agent.sim_trackers",
        ),
        # Forbidden third-party modules.
        (
            {"ubitrack_agent/core/bad.py": "import zenoh\n"},
            "ubitrack_agent.core may not import zenoh",
        ),
        (
            {"ubitrack_agent/agent/bad.py": "import cv2\n"},
            "ubitrack_agent.agent may not import cv2",
        ),
        # The bare folder name (what the repository's root on sys.path would shadow).
        (
            {"sim_trackers/bad.py": "from services import registry\n"},
            "imports services.registry, which is in no layer",
        ),
        # A module outside every layer.
        ({"ubitrack_agent/stray.py": "x = 1\n"}, "ubitrack_agent.stray: in no layer"),
    ],
)
def test_the_checker_catches_a_broken_tree(tmp_path, files, expected):
    found = violations(_tree(tmp_path, files))
    assert any(expected in problem for problem in found), found


def test_the_checker_accepts_downward_imports(tmp_path):
    tree = _tree(
        tmp_path,
        {
            "ubitrack_agent/agent/ok.py": "from ubitrack_agent.graph import planner\n",
            "sim_trackers/ok.py": "from ubitrack_agent.io.provider import Provider\n",
            "ubitrack_agent/commands/ok.py": (
                "def run():\n    import ubitrack_agent.sim_trackers.world\n"
            ),
        },
    )
    assert violations(tree) == []


@pytest.mark.parametrize(
    "modules, absent",
    [
        ("ubitrack_agent.core, ubitrack_agent.core.poses", ("zenoh", "networkx", "cv2")),
        ("ubitrack_agent.agent.runtime", ("cv2", SERVICES, SIMULATORS)),
        # The agent's command runs on a small machine without OpenCV or SciPy (--no-host).
        ("ubitrack_agent.commands.agent", ("cv2", "scipy", f"{SERVICES}.host_manager")),
        ("ubitrack_agent.agent.clocks", ("cv2", "scipy", SERVICES)),  # for the runtime
    ],
)
def test_importing_a_layer_loads_nothing_above_it(modules, absent):
    """The same rule at run time: what a layer's import pulls in, transitively."""
    code = f"import sys, {modules}; print(sorted(m for m in {absent!r} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_tests_and_benchmarks_import_the_installed_names_only():
    """``import services...`` from the repository's root would load a second copy of a module
    (under another name) beside the ``ubitrack_agent.services`` one the product uses."""
    bare = [
        f"{path.relative_to(ROOT)}:{line}: {name}"
        for top in ("tests", "bench")
        for path in sorted((ROOT / top).rglob("*.py"))
        for line, name in imports(path, module_name(ROOT, path))
        if name.split(".")[0] in MAPPED
    ]
    assert not bare, "\n".join(bare)
