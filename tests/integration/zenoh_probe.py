"""A zenoh session in a process of its own that answers a test's questions over its standard
input and output: the test's eyes inside a network namespace, where the test process itself
cannot open a session (``tests/integration/netns.py``).

Run ``python -m tests.integration.zenoh_probe [zenoh flags]``; each line of input is one
request, answered by one JSON line:

* ``get KEY``: the payloads of the replies to a query on ``KEY`` (base64), ``[]`` if none;
* ``next KEY``: the payload of the next sample put on ``KEY`` within 10 s (base64), or null;
* ``alive KEY``: the liveliness tokens matching ``KEY`` (their keys).

:class:`Probe` is the test's side.
"""

from __future__ import annotations

import argparse
import base64
import json
import queue
import subprocess
import sys
import threading
from typing import Any

from ubitrack_agent.net import config
from ubitrack_agent.net.session import open_session

QUERY_TIMEOUT_S = 2.0
"""Longest wait for the replies to a query (the agent answers in milliseconds)."""
NEXT_TIMEOUT_S = 10.0
"""Longest wait for a sample on ``next``."""


def _answer(session: Any, verb: str, key: str) -> Any:
    if verb == "get":
        replies = session.get(key, timeout=QUERY_TIMEOUT_S)
        return [_b64(r.ok.payload.to_bytes()) for r in replies if r.ok is not None]
    if verb == "alive":
        replies = session.liveliness().get(key, timeout=QUERY_TIMEOUT_S)
        return sorted(str(r.ok.key_expr) for r in replies if r.ok is not None)
    if verb == "next":
        samples: queue.SimpleQueue[bytes] = queue.SimpleQueue()
        subscriber = session.declare_subscriber(key, lambda s: samples.put(s.payload.to_bytes()))
        try:
            return _b64(samples.get(timeout=NEXT_TIMEOUT_S))
        except queue.Empty:
            return None
        finally:
            subscriber.undeclare()
    raise ValueError(f"unknown request {verb!r}")


def _b64(payload: bytes) -> str:
    return base64.b64encode(payload).decode("ascii")


def main() -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.integration.zenoh_probe")
    config.add_arguments(parser)
    settings = config.from_arguments(parser.parse_args(), role="member")
    with open_session(settings) as session:
        print(json.dumps("ready"), flush=True)
        for line in sys.stdin:
            verb, _, key = line.strip().partition(" ")
            print(json.dumps(_answer(session, verb, key)), flush=True)
    return 0


class Probe:
    """The test's side of a probe process started with stdin and stdout as text pipes."""

    def __init__(self, process: subprocess.Popen, timeout: float = 30.0) -> None:
        self.process = process
        self._lines: queue.SimpleQueue[str] = queue.SimpleQueue()
        threading.Thread(target=self._read_lines, daemon=True).start()
        if self._read(timeout) != "ready":  # a client waits for its router to open
            raise RuntimeError("the probe did not start")

    def _read_lines(self) -> None:
        for line in self.process.stdout:
            self._lines.put(line)
        self._lines.put("")

    def _read(self, timeout: float) -> Any:
        try:
            line = self._lines.get(timeout=timeout)
        except queue.Empty:
            raise RuntimeError(f"the probe did not answer within {timeout} s") from None
        if not line:
            raise RuntimeError(f"the probe ended (status {self.process.poll()})")
        return json.loads(line)

    def _ask(self, verb: str, key: str) -> Any:
        self.process.stdin.write(f"{verb} {key}\n")
        self.process.stdin.flush()
        return self._read(NEXT_TIMEOUT_S + QUERY_TIMEOUT_S + 5.0)

    def get(self, key: str) -> list[bytes]:
        """The payloads of the replies to a query on ``key``."""
        return [base64.b64decode(payload) for payload in self._ask("get", key)]

    def get_json(self, key: str) -> Any:
        """The first reply to a query on ``key`` as JSON, None if nothing answers."""
        replies = self.get(key)
        return json.loads(replies[0]) if replies else None

    def next(self, key: str) -> bytes | None:
        """The next sample put on ``key`` (None if none within 10 s)."""
        payload = self._ask("next", key)
        return None if payload is None else base64.b64decode(payload)

    def alive(self, key: str) -> list[str]:
        """The liveliness tokens matching ``key``."""
        return self._ask("alive", key)


if __name__ == "__main__":
    sys.exit(main())
