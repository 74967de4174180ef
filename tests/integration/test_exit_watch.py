"""The host manager's exit watch (``services/exit_watch.py``) with real processes: a watched
process killed is reported with its pid; one gone cannot be watched."""

import os
import queue
import signal
import subprocess
import sys

from ubitrack_agent.services.exit_watch import ExitWatch


def test_a_killed_process_is_reported_and_a_gone_one_cannot_be_watched():
    ended: queue.SimpleQueue[int] = queue.SimpleQueue()
    watch = ExitWatch(ended.put)
    sleepers = [
        subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"]) for _ in range(2)
    ]
    try:
        assert all(watch.watch(process.pid) for process in sleepers)
        os.kill(sleepers[1].pid, signal.SIGKILL)
        try:
            reported = ended.get(timeout=10)
        except queue.Empty:
            raise AssertionError("the killed process was not reported within 10 s") from None
        assert reported == sleepers[1].pid
        assert sleepers[0].poll() is None and ended.empty()  # the other runs, unreported
        sleepers[1].wait()
        gone = subprocess.Popen([sys.executable, "-c", "pass"])
        gone.wait()  # reaped: its pid names no process any more
        assert not watch.watch(gone.pid)
    finally:
        watch.close()
        for process in sleepers:
            process.kill()
            process.wait()
