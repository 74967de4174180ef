"""The plain-zenoh client of ``docs/protocol.md`` ("Measurements on the wire") works as printed
(issue 31, item 4): the Python block holding ``zenoh.Config()`` is taken from the document and
run in a process of its own against a live relation; it prints a decoded sample.

Only what a reader would change is changed: the hub's endpoint, the key root (the test's own
port and domain) and the relation (``C->A`` of the demo's world becomes the test tracker's
``WT->HT``). Everything else, the config, the query token, the decoding, runs as written.
"""

from __future__ import annotations

import re
import selectors
import subprocess
import sys
from pathlib import Path

import pytest

from tests.integration.test_agent import Setup, opened

pytestmark = pytest.mark.integration

PROTOCOL = Path(__file__).resolve().parents[2] / "docs" / "protocol.md"


def client_snippet() -> str:
    """The one Python block of ``docs/protocol.md`` that opens a ``zenoh.Config()``."""
    blocks = re.findall(r"```python\n(.*?)```", PROTOCOL.read_text(), flags=re.DOTALL)
    (snippet,) = [block for block in blocks if "zenoh.Config()" in block]
    return snippet


def test_the_snippet_names_the_endpoint_and_turns_multicast_off():
    snippet = client_snippet()
    assert 'insert_json5("connect/endpoints", \'["tcp/127.0.0.1:7448"]\')' in snippet
    assert 'insert_json5("scouting/multicast/enabled", "false")' in snippet
    assert "zenoh.open(config)" in snippet and "zenoh.open(zenoh.Config())" not in snippet


@pytest.fixture
def setup(processes):
    yield from opened(processes)


def test_the_documented_client_receives_a_live_sample(setup: Setup, processes):
    setup.start_agent()
    setup.tracker("art", "ART", 30.0, 2.0)
    snippet = (
        client_snippet()
        .replace("tcp/127.0.0.1:7448", f"tcp/127.0.0.1:{setup.port}")
        .replace("ubitrack/default/", f"{setup.keys.root}/")
        .replace("/C/A/6D/", "/WT/HT/6D/")
    )
    assert snippet.count(setup.keys.root) == 2 and str(setup.port) in snippet
    client = subprocess.Popen(
        [sys.executable, "-c", snippet],
        stdout=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    processes.append(client)  # ended by the fixture, pass or fail
    with selectors.DefaultSelector() as selector:  # the first sample, decoded and printed
        selector.register(client.stdout, selectors.EVENT_READ)
        assert selector.select(timeout=60), "the documented client printed nothing in 60 s"
    line = client.stdout.readline()
    assert line.startswith("{'type': 'ErrorPose', 't': "), line  # the fused pose, decoded
    assert "'rotation': array([" in line and "'translation': array([" in line
