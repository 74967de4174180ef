"""``ubitrack store`` says what it serves from its first line (issue 31, item 4): a missing
file is a new, empty store, said as such (a mistyped path shows at once instead of a store
silently serving 0 edges); an existing file's edges are counted; a missing folder, where no
save could ever be written, is refused."""

from __future__ import annotations

import selectors
import subprocess
import sys
from pathlib import Path

import pytest

from tests.integration.zenoh_helpers import free_port, member_flags

pytestmark = pytest.mark.integration

ONE_EDGE = (
    "provider: store\n"
    "edges:\n"
    "  - {from: C, to: HT, type: 6D, rotation: [0, 0, 0, 1], translation: [0.03, -0.06, 0.04]}\n"
)

STORE = [sys.executable, "-m", "ubitrack_agent.cli", "store"]


def nobody() -> list[str]:
    """Flags joining a network of its own (the store runs without an agent)."""
    port = free_port()
    return member_flags(port, f"store{port}")


def first_line(processes: list[subprocess.Popen], path: Path) -> str:
    """The first line ``ubitrack store PATH`` prints (the process is ended by the fixture)."""
    store = subprocess.Popen(
        [*STORE, str(path), "--quiet", *nobody()],
        stdout=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    processes.append(store)
    with selectors.DefaultSelector() as selector:
        selector.register(store.stdout, selectors.EVENT_READ)
        assert selector.select(timeout=60), "ubitrack store printed nothing within 60 s"
    return store.stdout.readline()


def test_a_missing_file_is_said_to_be_a_new_empty_store(processes, tmp_path: Path):
    line = first_line(processes, tmp_path / "calibraton.yaml")
    assert f"{tmp_path / 'calibraton.yaml'} does not exist: a new, empty store (0 edges)" in line
    assert "the first `ubitrack calibrate ... --save` creates the file" in line
    assert not (tmp_path / "calibraton.yaml").exists()  # nothing written before a save


def test_an_existing_file_is_served_with_its_edges_counted(processes, tmp_path: Path):
    path = tmp_path / "calibration.yaml"
    path.write_text(ONE_EDGE)
    line = first_line(processes, path)
    assert line.startswith(f"ubitrack store: serving 1 edge(s) of {path} on "), line


def test_a_missing_folder_is_refused(tmp_path: Path):
    path = tmp_path / "no-such-folder" / "calibration.yaml"
    out = subprocess.run(
        [*STORE, str(path), *nobody()],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2, out.stderr
    assert f"{tmp_path / 'no-such-folder'} is not a folder" in out.stderr
