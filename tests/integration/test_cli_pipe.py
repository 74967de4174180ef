"""The ``ubitrack`` command writing into a pipe its reader has closed (``ubitrack plan ... |
head``): it ends quietly with a shell's SIGPIPE code, no traceback."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "paper_tracking.yaml"


def test_a_closed_pipe_ends_the_command_quietly():
    command = [sys.executable, "-m", "ubitrack_agent.cli", "plan", str(EXAMPLE)]
    command += ["--from", "C", "--to", "A", "--type", "6D", "--all"]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        process.stdout.close()  # the reader gone before the first line is written
        _, errors = process.communicate(timeout=120)
    finally:
        process.kill()
        process.wait()
    assert process.returncode == 141, errors.decode()
    assert b"Traceback" not in errors and b"Exception ignored" not in errors, errors.decode()
