"""Shared fixtures of the planner tests: the shipped templates and the paper's setups."""

from __future__ import annotations

from pathlib import Path

import pytest

from ubitrack_agent.graph.srg import load_setup
from ubitrack_agent.graph.templates import load_templates

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def templates():
    return load_templates(ROOT / "templates")


@pytest.fixture(scope="session")
def tracking_setup():
    return load_setup(ROOT / "examples" / "paper_tracking.yaml")


@pytest.fixture(scope="session")
def calibration_setup():
    return load_setup(ROOT / "examples" / "paper_calibration.yaml")
