"""Nothing waits for a reader (``net.transport``, "Nothing waits for a reader"), with real
processes: a host manager whose containers are its zenoh clients (so it routes their samples),
and a reader stopped (SIGSTOP) while it reads: an application process reading a relation, or a
container whose component reads another container's output.

* A stopped reader holds neither the container serving it nor the host manager routing to it:
  the container's other flow keeps arriving, the stopped reader's samples are dropped on its
  full link (every put drops, after at most ``net.config.DROP_WAIT_US``), and the reader
  counts them ``missed`` and reads again when resumed.

Samples are lists of 2,000 positions (48 KB each), so that a stopped reader fills the links'
queues and the sockets' buffers within a second; the stops are shorter than zenoh's lease
(10 s). Until session 27 a component's data key put with BLOCK: the stopped container then
held every flow of the container it read from for the whole stop (up to zenoh's
``wait_before_close``, 5 s), which the second test's gap would show.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
import zenoh

from tests.integration.test_host import Network, network
from tests.integration.zenoh_helpers import member_flags, wait_until
from ubitrack_agent.core import encode
from ubitrack_agent.core.measurements import PositionList3D
from ubitrack_agent.net.host_protocol import StartGroup, encode_request
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.session import CONFIG_VARIABLE
from ubitrack_agent.net.spec import ComponentSpec, GroupSpec, InputBinding
from ubitrack_agent.net.transport import fetch_latest

pytestmark = pytest.mark.integration

PUT = "SampleKind.PUT"
FIRST_STAMP = 1_000
POINTS = np.zeros((2_000, 3))
"""A sample's positions: 48 KB encoded."""
STOP_S = 4.0
"""How long a reader is stopped: under zenoh's lease (10 s) and ``wait_before_close`` (5 s,
how long a BLOCK put waited: a gap that long is what the tests would see)."""
LONGEST_GAP_S = 2.0
"""Most time between two samples of the flow that is not stopped, while the other's reader
is: generous (it gets one every 10 ms, and a put waits at most 10 ms), and half the stop."""


@pytest.fixture
def hub(processes) -> Iterator[Network]:
    """The test's own session as the hub; a host manager is started by the test."""
    yield from network(processes, as_hub=True)


def relay(keys: KeySpace, instance: str, source: str, **changes) -> ComponentSpec:
    """A relay of ``source`` onto its data key ``<instance>/out``."""
    return ComponentSpec(
        instance=instance,
        service="relay",
        inputs=(
            InputBinding("in", source, trigger=True, from_worker=changes.pop("chained", False)),
        ),
        outputs={"out": keys.data(f"{instance}/out")},
        **changes,
    )


SMALL_BUFFERS = (
    "{ transport: { link: { tcp: { so_rcvbuf: 65536, so_sndbuf: 65536 } },"
    " shared_memory: { enabled: false } } }"
)
"""Zenoh options of the processes a test starts: 64 KB socket buffers (``so_rcvbuf``,
``so_sndbuf``) rather than the megabytes Linux lets them grow to, and no shared memory (zenoh
1.x puts a message of 3 KB or more between processes of one machine in a 16 MB shared pool and
sends only its reference: ``transport/shared_memory/transport_optimization``), so that a stopped
reader's link fills within the stop."""


@pytest.fixture
def small_buffers(tmp_path, monkeypatch) -> None:
    """:data:`SMALL_BUFFERS` for the processes the test starts from now on (``ZENOH_CONFIG``,
    which ``net.session`` starts from)."""
    path = tmp_path / "small_buffers.json5"
    path.write_text(SMALL_BUFFERS)
    monkeypatch.setenv(CONFIG_VARIABLE, str(path))


def start_groups(hub: Network, *groups: GroupSpec) -> None:
    """Start each group in a container of host manager ``lab`` and wait for its tokens."""
    events = hub.tokens()
    for group in groups:
        ok, reply = hub.ask("lab", encode_request(StartGroup(group)))
        assert ok, reply
    names = {spec.instance for group in groups for spec in group.components}
    wait_until(lambda: names <= {i for kind, i, _ in events if kind == PUT}, timeout=30)


def container_pid(hub: Network, name: str) -> int:
    return hub.status("lab")["containers"][name]["pid"]


def counters_if_answered(hub: Network, instance: str) -> dict | None:
    """The component's counters, None if its status did not answer within 2 s (a container
    draining a 72 MB backlog on a loaded machine may not: asked again by the caller)."""
    payloads = fetch_latest(hub.session, hub.keys.status(instance), timeout=2.0)
    return json.loads(payloads[0])["counters"] if payloads else None


def component_counters(hub: Network, instance: str) -> dict:
    """The component's counters, asked until its status answers (one 2 s question went
    unanswered in CI twice, the container still busy after its backlog)."""
    return wait_until(lambda: counters_if_answered(hub, instance), timeout=30)


def received(hub: Network, instance: str) -> int:
    return (counters_if_answered(hub, instance) or {}).get("received", 0)


@contextlib.contextmanager
def feeding(hub: Network, names: str) -> Iterator[Iterator[int]]:
    """The hub's sources ``src/<name>``, one for each of ``names``, each putting a sample every
    10 ms until the block ends; yields the stamps still to come."""
    keys = hub.keys
    sources = [hub.session.declare_publisher(keys.data(f"src/{name}")) for name in names]
    wait_until(lambda: all(p.matching_status.matching for p in sources), timeout=10)
    stop = threading.Event()
    stamps = iter(range(FIRST_STAMP, 10**9))

    def provide() -> None:
        while not stop.wait(0.01):
            stamp = next(stamps)
            for publisher in sources:
                publisher.put(encode(PositionList3D(stamp, POINTS)))

    provider = threading.Thread(target=provide, daemon=True)
    provider.start()
    try:
        yield stamps
    finally:
        stop.set()
        provider.join()


def paused(pid: int) -> tuple[float, float]:
    """Stop process ``pid`` (SIGSTOP) for :data:`STOP_S`, then resume it, whatever happens;
    when it was stopped and resumed."""
    os.kill(pid, signal.SIGSTOP)
    try:
        stopped_at = time.monotonic()
        time.sleep(STOP_S)
        return stopped_at, time.monotonic()
    finally:
        os.kill(pid, signal.SIGCONT)


def largest_gap(
    arrivals: list[tuple[float, object]], stopped_at: float, resumed_at: float
) -> float:
    """The longest time without an arrival between the stop and the resume."""
    during = [t for t, _ in arrivals if stopped_at <= t <= resumed_at]
    return max(b - a for a, b in itertools.pairwise([stopped_at, *during, resumed_at]))


def test_a_stopped_application_holds_neither_its_container_nor_the_host_manager(
    hub, processes, small_buffers
):
    keys = hub.keys
    hub.host("lab", pool_size=1)
    stopped, flowing = RelationId("W", "Stopped", "3D"), RelationId("W", "Flowing", "3D")
    group = GroupSpec(
        "lab-0",
        (
            relay(keys, "a", keys.data("src/a"), relations={"out": (keys.relation(stopped),)}),
            relay(keys, "b", keys.data("src/b"), relations={"out": (keys.relation(flowing),)}),
        ),
    )
    start_groups(hub, group)
    arrivals: list[tuple[float, object]] = []
    hub.session.declare_subscriber(
        keys.relation(flowing), lambda s: arrivals.append((time.monotonic(), s.congestion_control))
    )
    reader = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "tests.integration.relation_reader",
            "--frames",
            stopped.source,
            stopped.target,
            stopped.type,
            *member_flags(hub.port, hub.domain),
        ],
        start_new_session=True,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    processes.append(reader)

    def ask() -> dict:
        reader.stdin.write("?\n")
        reader.stdin.flush()
        return json.loads(reader.stdout.readline())

    assert json.loads(reader.stdout.readline()) == {"ready": True}
    with feeding(hub, "ab") as stamps:
        wait_until(lambda: ask()["received"] >= 20, timeout=20)
        stopped_at, resumed_at = paused(reader.pid)
        resumed_stamp = next(stamps)
        after = wait_until(lambda: (a := ask())["newest"] > resumed_stamp and a, timeout=20)

    # The other relation of the same container flowed all along, as a relation drops.
    assert largest_gap(arrivals, stopped_at, resumed_at) < LONGEST_GAP_S
    assert all(cc == zenoh.CongestionControl.DROP for _, cc in arrivals)
    # The stop filled its link: zenoh dropped samples there, and the application counted them;
    # resumed, it reads the relation again (above: a sample stamped after it resumed).
    assert after["missed"] > 0
    counters = component_counters(hub, "a")
    assert after["received"] + after["missed"] <= counters["published"]


def test_a_stopped_component_holds_neither_the_container_it_reads_nor_its_other_flows(
    hub, small_buffers
):
    keys = hub.keys
    hub.host("lab", pool_size=2)
    producer = relay(keys, "producer", keys.data("src/p"))
    other = relay(keys, "other", keys.data("src/o"))
    consumer = relay(keys, "consumer", keys.data("producer/out"), chained=True)
    start_groups(hub, GroupSpec("lab-0", (producer, other)), GroupSpec("lab-1", (consumer,)))
    arrivals: list[tuple[float, object]] = []
    hub.session.declare_subscriber(
        keys.data("other/out"), lambda s: arrivals.append((time.monotonic(), s.congestion_control))
    )
    consumer_pid = container_pid(hub, "lab-1")
    with feeding(hub, "po"):
        wait_until(lambda: received(hub, "consumer") >= 20, timeout=20)
        stopped_at, resumed_at = paused(consumer_pid)
        before = component_counters(hub, "consumer")["received"]
        wait_until(lambda: received(hub, "consumer") >= before + 20, timeout=30)

    # The producer's container went on with its other flow all through the stop.
    assert largest_gap(arrivals, stopped_at, resumed_at) < LONGEST_GAP_S
    assert all(cc == zenoh.CongestionControl.DROP for _, cc in arrivals)
    # The stop filled the consumer's link: zenoh dropped samples there, the consumer counted
    # them, and every sample the producer put either arrived or was counted.
    got = component_counters(hub, "consumer")
    assert got["missed"] > 0
    assert got["received"] + got["missed"] <= component_counters(hub, "producer")["published"]
