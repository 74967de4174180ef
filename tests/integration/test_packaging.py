"""A normal (non-editable) install works: the wheel carries the templates and the scenarios,
and the installed package plans from any directory, without the source tree beside it."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]
PIP = (sys.executable, "-m", "pip")
SHIPPED = (
    "pyproject.toml",
    "setup.py",
    "README.md",
    "ubitrack_agent",
    "services",
    "sim_trackers",
    "templates",
)


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel built from a copy of the sources (so the checkout gets no build files)."""
    source = tmp_path_factory.mktemp("source")
    for name in SHIPPED:
        origin = ROOT / name
        if origin.is_dir():
            shutil.copytree(origin, source / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(origin, source / name)
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run(
        [
            *PIP,
            "wheel",
            "--quiet",
            "--no-deps",
            "--no-build-isolation",
            "-w",
            str(out),
            str(source),
        ],
        check=True,
    )
    (built,) = out.glob("ubitrack_agent-*.whl")
    return built


def test_the_wheel_carries_every_template_scenario_and_page(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    templates = {p.name for p in (ROOT / "templates").glob("*.yaml")}
    assert templates and {f"ubitrack_agent/templates/{name}" for name in templates} <= names
    assert "ubitrack_agent/sim_trackers/scenarios/paper_figure1.yaml" in names
    assert "ubitrack_agent/services/worker.py" in names
    # One top-level name: nothing another distribution or a user's folder is likely to have.
    assert {name.split("/")[0].split("-")[0] for name in names} == {"ubitrack_agent"}
    view = "ubitrack_agent/commands/view"
    pages = {f"{view}/{p.name}" for p in (ROOT / view).glob("*.*") if p.suffix != ".py"}
    assert pages and pages <= names  # ubitrack view's page, script and style
    assert not any(name.startswith(("tests/", "bench/")) for name in names)


def decoy_distribution(where: Path) -> Path:
    """A distribution of another project with top-level packages named as the repository's
    folders (``services``, ``templates``, ``sim_trackers``), built as a wheel."""
    for name in ("services", "sim_trackers", "templates"):
        (where / name).mkdir(parents=True)
        (where / name / "__init__.py").write_text(f"DECOY = {name!r}\n")
    (where / "pyproject.toml").write_text(
        '[project]\nname = "decoy-services"\nversion = "1.0"\n'
        '[tool.setuptools]\npackages = ["services", "sim_trackers", "templates"]\n'
    )
    out = where / "dist"
    build = [*PIP, "wheel", "--quiet", "--no-deps", "--no-build-isolation", "-w", str(out)]
    subprocess.run([*build, str(where)], check=True)
    (built,) = out.glob("decoy_services-*.whl")
    return built


def test_the_installed_package_plans_figure_6_from_another_directory(wheel, tmp_path):
    """Installed beside another distribution whose top-level packages are named ``services``,
    ``templates`` and ``sim_trackers``: both import, neither replaces the other."""
    target, work = tmp_path / "site", tmp_path / "elsewhere"
    work.mkdir()
    decoy = decoy_distribution(tmp_path / "decoy")
    subprocess.run(
        [
            *PIP,
            "install",
            "--quiet",
            "--no-deps",
            "--no-index",
            "--target",
            str(target),
            str(wheel),
            str(decoy),
        ],
        check=True,
    )
    setup = shutil.copy(ROOT / "examples" / "paper_tracking.yaml", work / "setup.yaml")
    # The installed copy comes first on the path; the checkout is neither the working
    # directory nor on PYTHONPATH.
    env = {**os.environ, "PYTHONPATH": str(target)}
    where = subprocess.run(
        [
            sys.executable,
            "-c",
            "import ubitrack_agent.templates, services; "
            "print(ubitrack_agent.templates.__file__, services.DECOY)",
        ],
        cwd=work,
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    assert where.stdout.startswith(str(target)) and where.stdout.split()[1] == "services"
    query = ("--from", "C", "--to", "A", "--type", "6D")
    plan = subprocess.run(
        [sys.executable, "-m", "ubitrack_agent.cli", "plan", str(setup), *query],
        cwd=work,
        env=env,
        capture_output=True,
        text=True,
    )
    assert plan.returncode == 0, plan.stderr
    assert plan.stdout.startswith("6D C->A: 4 solution(s)")
    assert "MultiTrackerFusion (space)" in plan.stdout  # figure 6: both trackers fused
    assert "PoseEstimation2D3D (space)" in plan.stdout
