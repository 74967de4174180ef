"""A command's output lines stay whole beside log lines of other threads on one file
(``ubitrack_agent.core.lines``): the JSON lines ``ubitrack subscribe``, ``demo --json``,
``calibrate --json`` and ``record --json`` print, read from a log their standard error shares
(``tests/integration/test_hosts_netns.py`` once read ``{...}<a warning>`` there)."""

from __future__ import annotations

import json
import subprocess
import sys

SCRIPT = """
import json, logging, threading
from ubitrack_agent.core.lines import write_line
logging.basicConfig(level=logging.WARNING)
log = logging.getLogger("beside")
done = threading.Event()
def warn():
    while not done.is_set():
        log.warning("a sample not after the newest: kept for lookups, not passed on")
thread = threading.Thread(target=warn)
thread.start()
for i in range(LINES):
    write_line(json.dumps({"n": i, "covariance": "x" * 1100}))
done.set()
thread.join()
"""
LINES = 5000


def test_json_lines_are_whole_beside_a_thread_logging_to_the_same_file(tmp_path):
    log = tmp_path / "out.log"
    with log.open("wb") as out:
        subprocess.run(
            [sys.executable, "-c", SCRIPT.replace("LINES", str(LINES))],
            stdout=out,
            stderr=out,
            check=True,
            timeout=120,
        )
    lines = log.read_bytes().split(b"\n")
    samples = [json.loads(line) for line in lines if line.startswith(b"{")]
    assert [s["n"] for s in samples] == list(range(LINES))
    assert any(b"not passed on" in line for line in lines)  # the other thread did log beside
