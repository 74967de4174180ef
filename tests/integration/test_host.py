"""The host manager (``services/host.py``) with real zenoh on loopback and real processes:
start, stop and status requests, refusals, exit reports, and an agent using a host manager it
did not start."""

from __future__ import annotations

import contextlib
import json
import os
import queue
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from subprocess import PIPE

import pytest

from tests.integration.conftest import kill_tagged
from tests.integration.zenoh_helpers import Collector, free_port, member_flags, wait_until
from ubitrack_agent.core import Pose, decode, encode
from ubitrack_agent.io.application import Relation
from ubitrack_agent.net import config
from ubitrack_agent.net.host_protocol import (
    MAX_MESSAGE_BYTES,
    STOP_COMMAND,
    Exited,
    Start,
    StartedGroup,
    StartGroup,
    Status,
    Stop,
    encode_request,
)
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.session import open_session
from ubitrack_agent.net.spec import ComponentSpec, GroupSpec, InputBinding
from ubitrack_agent.net.transport import fetch_latest
from ubitrack_agent.services.host_claim import NAME_TAKEN

pytestmark = pytest.mark.integration

PUT = "SampleKind.PUT"


@dataclass
class Network:
    port: int
    domain: str
    keys: KeySpace
    session: object
    processes: list
    watches: list = field(default_factory=list)

    def start(
        self,
        *command: str,
        host_name: str | None = None,
        stdin: int | None = None,
        stderr: int | None = None,
    ) -> subprocess.Popen:
        """A process joining the network, on host ``host_name`` (default this machine's), with
        ``stdin`` as its standard input (``subprocess.PIPE``: a pipe from the test) and
        ``stderr`` as its standard error (``PIPE``: read as text by the test)."""
        named = [] if host_name is None else ["--host-name", host_name]
        process = subprocess.Popen(
            [sys.executable, *command, *member_flags(self.port, self.domain), *named],
            start_new_session=True,
            stdin=stdin,
            stderr=stderr,
            text=stderr is not None,
        )
        self.processes.append(process)
        return process

    def host(
        self,
        name: str,
        pool_size: int,
        *via: str,
        as_the_agent_starts_it: bool = False,
        options: tuple[str, ...] = (),
    ) -> subprocess.Popen:
        """A host manager (``python -m ubitrack_agent.services.host``, or ``via`` another entry
        point) with ``options``; ``as the agent starts it``: reading a pipe from the test (it closes
        when the agent dies)."""
        entry = via or ("-m", "ubitrack_agent.services.host")
        options = (*options, "--started-by-agent") if as_the_agent_starts_it else options
        process = self.start(
            *entry,
            "--name",
            name,
            "--pool-size",
            str(pool_size),
            *options,
            stdin=subprocess.PIPE if as_the_agent_starts_it else None,
        )
        wait_until(lambda: self.ask(name, encode_request(Status()))[0], timeout=30)
        return process

    def ask(self, host: str, payload: bytes | str | None) -> tuple[bool, dict]:
        """(success, reply) of one request; (False, {}) without an answer."""
        extra = {} if payload is None else {"payload": payload}
        replies = list(self.session.get(self.keys.host_request(host), timeout=5.0, **extra))
        if not replies:
            return False, {}
        reply = replies[0]
        answer = reply.ok if reply.ok is not None else reply.err
        return reply.ok is not None, json.loads(answer.payload.to_bytes())

    def status(self, host: str) -> dict:
        ok, answer = self.ask(host, encode_request(Status()))
        assert ok, answer
        return answer

    def tokens(self) -> list[tuple[str, str, float]]:
        """Worker token events (kind, instance, time) from now on, appended as they come."""
        events: list[tuple[str, str, float]] = []
        watch = self.session.liveliness().declare_subscriber(
            self.keys.all_workers(),
            lambda s: events.append(
                (str(s.kind), self.keys.parse_worker(str(s.key_expr))[0], time.monotonic())
            ),
        )
        self.watches.append(watch)
        return events

    def agent(self, *extra: str, entry: tuple[str, ...] = ("-m", "ubitrack_agent.cli")):
        """``ubitrack agent`` with ``extra`` options (``entry``: how Python runs the CLI)."""
        process = subprocess.Popen(
            [
                sys.executable,
                *entry,
                "--log-level",
                "INFO",
                "agent",
                "--listen",
                f"tcp/127.0.0.1:{self.port}",
                "--domain",
                self.domain,
                *extra,
            ],
            start_new_session=True,
        )
        self.processes.append(process)
        wait_until(lambda: self.agent_status() is not None, timeout=20)
        return process

    def tracker(self, host_name: str | None = None) -> subprocess.Popen:
        """A noise-free tracker ART announcing ART->WT and ART->HT, on host ``host_name``."""
        tracker = ("--provider", "art", "--tracker", "ART", "--yaw", "30", "--x", "2")
        return self.start(
            "-m", "ubitrack_agent.sim_trackers.exact_tracker", *tracker, host_name=host_name
        )

    def agent_status(self) -> dict | None:
        replies = fetch_latest(self.session, self.keys.agent_status(), timeout=0.5)
        return json.loads(replies[0]) if replies else None


def network(processes: list, as_hub: bool) -> Iterator[Network]:
    port = free_port()
    domain = f"host{port}"
    hub = config.Settings(listen=(f"tcp/127.0.0.1:{port}",), domain=domain)
    settings = hub if as_hub else config.member_of(hub)
    with open_session(settings) as session:
        yield Network(port, domain, KeySpace(settings.key_prefix), session, processes)
    kill_tagged(domain)  # workers left on purpose by a killed parent


@pytest.fixture
def net(processes) -> Iterator[Network]:
    """A member session; the test starts an agent as the hub."""
    yield from network(processes, as_hub=False)


@pytest.fixture
def hub(processes) -> Iterator[Network]:
    """The test's own session as the hub (no agent)."""
    yield from network(processes, as_hub=True)


def relay(keys: KeySpace, instance: str, **changes) -> ComponentSpec:
    return ComponentSpec(
        instance=instance,
        service=changes.pop("service", "relay"),
        inputs=(InputBinding("in", keys.data("src/in"), trigger=True),),
        outputs={"out": keys.data(f"{instance}/out")},
        **changes,
    )


def tagged(domain: str) -> list[str]:
    """Processes whose command line names the test's domain."""
    found = subprocess.run(["pgrep", "-f", domain], capture_output=True, text=True).stdout
    return [pid for pid in found.split() if pid != str(os.getpid())]


def relayed(hub: Network, instance: str) -> tuple[Collector, object]:
    """A collector of ``instance``'s output and a publisher of its input, once a pose put
    there came out."""
    output = Collector(hub.session, hub.keys.data(f"{instance}/out"))
    source = hub.session.declare_publisher(hub.keys.data("src/in"))
    wait_until(lambda: source.matching_status.matching)
    source.put(encode(Pose(1_000, [0, 0, 0, 1], [1.0, 2.0, 3.0])))
    assert decode(output.next(), expected=Pose).timestamp_ns == 1_000
    return output, source


def test_start_stop_status_and_exit_reports(hub):
    keys = hub.keys
    tokens = hub.tokens()
    exits = Collector(hub.session, keys.host_exited("lab"))
    host = hub.host("lab", pool_size=1)
    wait_until(lambda: hub.status("lab")["pool_ready"] == 1, timeout=30)

    # A start goes to the ready pool member; the worker runs.
    ok, started = hub.ask("lab", encode_request(Start(relay(keys, "relay1"))))
    assert ok and not started["reused"], started
    wait_until(lambda: (PUT, "relay1") in [(k, i) for k, i, _ in tokens], timeout=20)
    relayed(hub, "relay1")
    status = hub.status("lab")
    assert status["instances"]["relay1"]["pid"] == started["pid"]
    assert status["counters"]["started_from_pool"] == 1

    # Asked again, it starts nothing.
    ok, again = hub.ask("lab", encode_request(Start(relay(keys, "relay1"))))
    assert ok and again["reused"] and again["run"] == started["run"], again

    # Killed: reported with its run, whatever the reason.
    os.kill(started["pid"], signal.SIGKILL)
    report = Exited.parse(exits.next(timeout=10))
    assert (report.instance, report.run, report.reason) == ("relay1", started["run"], "exited")

    # Released by a stop command from elsewhere: reported too, the process rejoins the pool.
    ok, second = hub.ask("lab", encode_request(Start(relay(keys, "relay2"))))
    assert ok, second
    wait_until(lambda: (PUT, "relay2") in [(k, i) for k, i, _ in tokens], timeout=20)
    hub.session.put(keys.control("relay2"), STOP_COMMAND)
    report = Exited.parse(exits.next(timeout=10))
    assert (report.instance, report.run, report.reason) == ("relay2", second["run"], "released")
    wait_until(lambda: hub.status("lab")["pool_ready"] == 1, timeout=10)

    # Stopped through the host manager: no report, the process goes back to the pool.
    ok, third = hub.ask("lab", encode_request(Start(relay(keys, "relay3"))))
    assert ok, third
    wait_until(lambda: (PUT, "relay3") in [(k, i) for k, i, _ in tokens], timeout=20)
    ok, stopped = hub.ask("lab", encode_request(Stop("relay3")))
    assert ok and stopped == {"instance": "relay3", "process": "released"}, stopped
    wait_until(lambda: ("SampleKind.DELETE", "relay3") in [(k, i) for k, i, _ in tokens])
    wait_until(lambda: hub.status("lab")["pool_ready"] == 1, timeout=10)
    status = hub.status("lab")
    assert status["instances"] == {}
    assert status["counters"]["exited"] == status["counters"]["released"] == 1
    with pytest.raises(queue.Empty):  # nothing more was reported
        exits.next(timeout=0.5)

    # SIGTERM: every worker it started ends with it, its pool member too.
    ok, last = hub.ask("lab", encode_request(Start(relay(keys, "relay4"))))
    assert ok, last
    host.send_signal(signal.SIGTERM)
    assert host.wait(timeout=15) == 0
    wait_until(lambda: not tagged(hub.domain), timeout=10)


def test_containers_start_with_a_group_take_additions_and_are_restored_when_killed(hub):
    """Issue 28: one request starts a group's components in one process (a pool member given
    the group); a later one adds to it without a process start; a container killed with its
    components is restored by the host manager and each is reported ``restored`` with the new
    pid; a component stopped on its own control key is reported released; the container ends
    with its last component."""
    keys = hub.keys
    tokens = hub.tokens()
    exits = Collector(hub.session, keys.host_exited("lab"))
    hub.host("lab", pool_size=1)
    wait_until(lambda: hub.status("lab")["pool_ready"] == 1, timeout=30)

    def up(*names: str) -> bool:
        seen = [(k, i) for k, i, _ in tokens]
        return all((PUT, name) in seen for name in names)

    group = GroupSpec("lab-0", (relay(keys, "relay1"), relay(keys, "relay2")))
    ok, reply = hub.ask("lab", encode_request(StartGroup(group)))
    assert ok, reply
    started = StartedGroup.parse(json.dumps(reply).encode())
    assert [s.instance for s in started.started] == ["relay1", "relay2"]
    assert {s.pid for s in started.started} == {started.pid}  # one process
    wait_until(lambda: up("relay1", "relay2"), timeout=20)
    output, source = relayed(hub, "relay1")
    status = hub.status("lab")
    assert status["counters"]["containers_from_pool"] == 1
    assert status["instances"]["relay2"]["container"] == "lab-0"
    assert status["containers"]["lab-0"] == {"pid": started.pid, "ready": True}

    # Another component of the container: added to the running process.
    ok, reply = hub.ask(
        "lab", encode_request(StartGroup(GroupSpec("lab-0", (relay(keys, "relay3"),))))
    )
    assert ok and reply["pid"] == started.pid, reply
    wait_until(lambda: up("relay3"), timeout=20)
    status = hub.status("lab")
    assert status["counters"]["added_to_containers"] == 1
    assert status["counters"].get("containers_cold", 0) == 0
    assert status["counters"].get("started_cold", 0) == 0

    # Killed: restored with its three components, in a new process, under their runs.
    runs = {s.instance: s.run for s in started.started}
    os.kill(started.pid, signal.SIGKILL)
    reports = [Exited.parse(exits.next(timeout=10)) for _ in range(3)]
    assert {r.instance for r in reports} == {"relay1", "relay2", "relay3"}
    assert {r.reason for r in reports} == {"restored"}
    new_pid = reports[0].pid
    assert new_pid != started.pid and {r.pid for r in reports} == {new_pid}
    assert {r.instance: r.run for r in reports if r.instance in runs} == runs
    wait_until(lambda: hub.status("lab")["containers"].get("lab-0", {}).get("ready"), timeout=30)
    output.drain()
    source.put(encode(Pose(2_000, [0, 0, 0, 1], [1.0, 2.0, 3.0])))
    assert decode(output.next(timeout=10), expected=Pose).timestamp_ns == 2_000
    assert hub.status("lab")["counters"]["containers_restored"] == 1

    # Stopped on its own control key: it leaves the container and is reported released.
    hub.session.put(keys.control("relay3"), STOP_COMMAND)
    report = Exited.parse(exits.next(timeout=10))
    assert (report.instance, report.reason) == ("relay3", "released")

    # Stopped through the host manager: removed; the container ends with the last one.
    for name in ("relay1", "relay2"):
        ok, stopped = hub.ask("lab", encode_request(Stop(name)))
        assert ok and stopped == {"instance": name, "process": "removed"}, stopped
    wait_until(lambda: hub.status("lab")["containers"] == {}, timeout=10)
    wait_until(lambda: not running(new_pid), timeout=10)
    with pytest.raises(queue.Empty):  # nothing more was reported
        exits.next(timeout=0.5)


def test_a_restored_container_runs_its_components_as_rewired(hub):
    """A component rewired in place (a control command from the agent, not through the host
    manager) runs as rewired after its container died and was restored, before anything
    rewires it again: the host manager followed the command."""
    keys = hub.keys
    tokens = hub.tokens()
    exits = Collector(hub.session, keys.host_exited("lab"))
    hub.host("lab", pool_size=1)
    wait_until(lambda: hub.status("lab")["pool_ready"] == 1, timeout=30)
    ok, reply = hub.ask("lab", encode_request(StartGroup(GroupSpec("lab-0", (relay(keys, "r"),)))))
    assert ok, reply
    wait_until(lambda: (PUT, "r") in [(k, i) for k, i, _ in tokens], timeout=30)
    output, old_source = relayed(hub, "r")
    inputs = [{"port": "in", "key": keys.data("src/moved"), "trigger": True}]
    hub.session.put(keys.control("r"), json.dumps({"inputs": inputs}))
    source = hub.session.declare_publisher(keys.data("src/moved"))
    assert flows_again(source, output, 2_000)
    assert hub.status("lab")["counters"]["rewires_followed"] == 1

    os.kill(reply["pid"], signal.SIGKILL)
    report = Exited.parse(exits.next(timeout=10))
    assert (report.instance, report.reason) == ("r", "restored")
    assert flows_again(source, output, 3_000)  # nobody rewired the restored one
    output.drain()
    old_source.put(encode(Pose(4_000, [0, 0, 0, 1], [1.0, 2.0, 3.0])))
    source.put(encode(Pose(5_000, [0, 0, 0, 1], [1.0, 2.0, 3.0])))
    later = []
    with contextlib.suppress(queue.Empty):
        while True:
            later.append(decode(output.next(timeout=1.0), expected=Pose).timestamp_ns)
    assert 5_000 in later and 4_000 not in later  # the input it was started with is unread


def sockets(pid: int) -> int:
    """Open sockets of process ``pid`` (``/proc/<pid>/fd`` links to ``socket:``)."""
    links = (os.readlink(f"/proc/{pid}/fd/{fd}") for fd in os.listdir(f"/proc/{pid}/fd"))
    return sum(link.startswith("socket:") for link in links)


def test_workers_are_clients_holding_one_link_and_reach_the_hub_when_their_host_manager_dies(
    hub,
):
    """Issue 28, "Fewer links": by default a container is a zenoh client of its host manager,
    one socket where a peer links to every other process, and its data flows through the host
    manager; killed, the host manager no longer carries it, and the container, which outlives
    it, reaches the network through the hub instead."""
    keys = hub.keys
    tokens = hub.tokens()
    host = hub.host("lab", pool_size=1)
    wait_until(lambda: hub.status("lab")["pool_ready"] == 1, timeout=30)
    group = GroupSpec("lab-0", (relay(keys, "relay1"),))
    ok, reply = hub.ask("lab", encode_request(StartGroup(group)))
    assert ok, reply
    wait_until(lambda: (PUT, "relay1") in [(k, i) for k, i, _ in tokens], timeout=20)
    output, source = relayed(hub, "relay1")
    assert sockets(reply["pid"]) == 1
    host.kill()
    host.wait(timeout=10)
    assert flows_again(source, output, 3_000)
    assert running(reply["pid"])


def test_workers_as_peers_link_to_every_process(hub):
    """``--workers-as-peers``: the container is a peer, listening, linked to the hub and the
    host manager besides."""
    keys = hub.keys
    tokens = hub.tokens()
    hub.host("lab", pool_size=0, options=("--workers-as-peers",))
    ok, reply = hub.ask("lab", encode_request(StartGroup(GroupSpec("lab-0", (relay(keys, "r"),)))))
    assert ok, reply
    wait_until(lambda: (PUT, "r") in [(k, i) for k, i, _ in tokens], timeout=30)
    relayed(hub, "r")
    # a peer: its listener and links to the hub and the host manager at least (a client holds
    # one socket); gossip links it to the test's session too, but not always within seconds
    wait_until(lambda: sockets(reply["pid"]) >= 3, timeout=10)


def test_a_gateway_port_taken_before_zenoh_binds_it_is_replaced_by_another(monkeypatch):
    """The workers' gateway port is chosen free and bound by zenoh a moment later; taken in
    between (as by another process's listener: CI stop 39), the host manager's session is opened
    on another port, and its workers' flags name the port it listens on."""
    from ubitrack_agent.services import host

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        busy = taken.getsockname()[1]
        offered = iter([busy, free_port()])
        monkeypatch.setattr(host, "free_loopback_port", lambda: next(offered))
        settings = config.Settings(listen=(f"tcp/127.0.0.1:{free_port()}",))
        session, flags = host.open_host_session(settings, gateway=True)
        with session:
            gateway = flags[flags.index("--connect") + 1]
            assert gateway.startswith("tcp/127.0.0.1:")
            port = int(gateway.rsplit(":", 1)[1])
            assert port != busy
            with socket.create_connection(("127.0.0.1", port), timeout=5):
                pass  # zenoh listens there


def test_a_host_manager_outlives_the_agent_that_started_it(hub):
    """The agent that started a host manager dies (its pipe closes): the host manager serves
    on, so its client container keeps its route and its data flows, the host manager still
    takes requests (from the agent's successor), and a second host manager of its name, as a
    successor agent might start one, gives way (exits saying so) instead of serving beside it.
    Killed (SIGKILL), the host manager leaves its container serving; the next one of its name
    adopts it, and restores it with its components when it dies in turn."""
    keys = hub.keys
    tokens = hub.tokens()
    host = hub.host("lab", pool_size=1, as_the_agent_starts_it=True)
    group = GroupSpec("lab-0", (relay(keys, "relay1"),))
    ok, reply = hub.ask("lab", encode_request(StartGroup(group)))
    assert ok, reply
    wait_until(lambda: (PUT, "relay1") in [(k, i) for k, i, _ in tokens], timeout=30)
    output, source = relayed(hub, "relay1")
    pid = hub.status("lab")["pid"]

    host.stdin.close()  # as when the agent that started it dies
    wait_until(lambda: hub.status("lab")["orphaned"], timeout=10)
    assert flows_again(source, output, 4_000)
    assert host.poll() is None and hub.status("lab")["pid"] == pid
    ok, reply = hub.ask("lab", encode_request(StartGroup(GroupSpec("lab-0", (relay(keys, "r2"),)))))
    assert ok, reply  # a successor agent's start
    wait_until(lambda: (PUT, "r2") in [(k, i) for k, i, _ in tokens], timeout=30)

    second = hub.start(
        "-m", "ubitrack_agent.services.host", "--name", "lab", "--pool-size", "0", stderr=PIPE
    )
    assert second.wait(timeout=30) == NAME_TAKEN
    assert "another host manager of this name serves already: exiting" in second.stderr.read()
    assert {hub.status("lab")["pid"]} == {pid}  # one host manager answers: the first

    # Killed: its container serves on; the next host manager of its name adopts it.
    container = hub.status("lab")["containers"]["lab-0"]["pid"]
    host.kill()
    host.wait(timeout=10)
    assert flows_again(source, output, 5_000)
    third = hub.host("lab", pool_size=1)
    status = wait_until(lambda: adopted(hub.status("lab"), 2), timeout=20)
    assert status["pid"] == third.pid
    assert status["containers"] == {"lab-0": {"pid": container, "ready": True}}
    assert {i: s["container"] for i, s in status["instances"].items()} == {
        "relay1": "lab-0",
        "r2": "lab-0",
    }
    exits = Collector(hub.session, keys.host_exited("lab"))
    os.kill(container, signal.SIGKILL)  # dies: restored by its adopter, with both components
    reports = [Exited.parse(exits.next(timeout=10)) for _ in range(2)]
    assert {(r.instance, r.reason) for r in reports} == {("relay1", "restored"), ("r2", "restored")}
    assert {r.run for r in reports} == {s["run"] for s in status["instances"].values()}
    assert flows_again(source, output, 6_000, timeout=30)
    assert hub.status("lab")["counters"]["containers_restored"] == 1


def adopted(status: dict, components: int) -> dict | None:
    """``status`` if its host manager adopted a container with ``components`` components."""
    counters = status["counters"]
    if counters.get("containers_adopted") == 1 and counters["components_adopted"] == components:
        return status
    return None


def flows_again(source, output: Collector, timestamp_ns: int, timeout: float = 10.0) -> bool:
    """Whether a pose put on ``source`` (again every 0.2 s) reaches ``output`` within
    ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        source.put(encode(Pose(timestamp_ns, [0, 0, 0, 1], [1.0, 2.0, 3.0])))
        try:
            if decode(output.next(timeout=0.2), expected=Pose).timestamp_ns == timestamp_ns:
                return True
        except queue.Empty:
            continue
    return False


def running(pid: int) -> bool:
    """Whether process ``pid`` runs (neither gone nor a zombie nobody reaped)."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as file:
            return file.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def test_of_two_host_managers_of_one_name_started_together_exactly_one_serves(hub):
    """Five pairs of ``ubitrack host`` of one name each, every process started at the same
    instant (ten at once on this machine: the links come up slowly): in every pair exactly one
    serves, and the other exits with ``NAME_TAKEN`` naming the one that came first."""
    pairs = {
        f"twin{index}": [
            hub.start(
                *("-m", "ubitrack_agent.cli", "host", "--name", f"twin{index}"),
                *("--pool-size", "0", "--quiet"),
                stderr=PIPE,
            )
            for _ in range(2)
        ]
        for index in range(5)
    }
    for name, pair in pairs.items():
        wait_until(lambda pair=pair: any(p.poll() is not None for p in pair), timeout=60)
        (loser,) = [p for p in pair if p.poll() is not None]
        (winner,) = [p for p in pair if p is not loser]
        message = loser.stderr.read()
        assert loser.returncode == NAME_TAKEN, (name, loser.returncode, message)
        came_first = f"host {name}: another host manager of this name (pid {winner.pid}) "
        assert came_first + "started first: exiting" in message or (
            f"host {name}: another host manager of this name serves already: exiting" in message
        ), message
        wait_until(lambda name=name: hub.ask(name, encode_request(Status()))[0], timeout=30)
        time.sleep(1.0)  # a second host manager serving would answer by now too
        replies = list(
            hub.session.get(
                hub.keys.host_request(name), payload=encode_request(Status()), timeout=5.0
            )
        )
        assert [json.loads(r.ok.payload.to_bytes())["pid"] for r in replies] == [winner.pid]
        assert winner.poll() is None
        winner.terminate()
        assert winner.wait(timeout=15) == 0


def test_workers_still_starting_when_their_host_manager_dies_exit(hub):
    """Chaos seed 210 (issue 11): the agent was SIGKILLed while its host manager started ten
    workers cold on a loaded machine; its host manager ended with it, and those workers, starved
    of CPU, were still importing 40 s later, never having declared their tokens, while the
    restarted agent had started ten others. A worker still starting when its host manager dies
    now exits; one already running keeps running, for a restarted agent to adopt.

    The starving is made deterministic: each cold worker is stopped (SIGSTOP) as soon as the
    host manager answers its start, long before it could declare its token (a cold start takes
    hundreds of milliseconds), and continued once the host manager is gone."""
    keys = hub.keys
    tokens = hub.tokens()
    host = hub.host("lab", pool_size=0, as_the_agent_starts_it=True)
    ok, kept = hub.ask("lab", encode_request(Start(relay(keys, "kept"))))
    assert ok, kept
    wait_until(lambda: (PUT, "kept") in [(k, i) for k, i, _ in tokens], timeout=30)

    starting = []
    for index in range(3):
        ok, started = hub.ask("lab", encode_request(Start(relay(keys, f"starting{index}"))))
        assert ok, started
        os.kill(started["pid"], signal.SIGSTOP)
        starting.append(started["pid"])
    host.kill()
    host.wait(timeout=15)
    host.stdin.close()
    for pid in starting:
        os.kill(pid, signal.SIGCONT)

    wait_until(lambda: not any(running(pid) for pid in starting), timeout=30)
    assert {i for _, i, _ in tokens} == {"kept"}, tokens  # none of them ever served
    assert running(kept["pid"])  # the worker already running outlives its host manager
    output = Collector(hub.session, keys.data("kept/out"))
    source = hub.session.declare_publisher(keys.data("src/in"))
    wait_until(lambda: source.matching_status.matching)
    source.put(encode(Pose(2_000, [0, 0, 0, 1], [1.0, 2.0, 3.0])))
    assert decode(output.next(), expected=Pose).timestamp_ns == 2_000


def test_unregistered_services_and_malformed_requests_are_refused(hub):
    keys = hub.keys
    hub.host("lab", pool_size=0)
    good = relay(keys, "good")
    refused = {
        "refused_spec": [
            encode_request(Start(relay(keys, "evil", service="os.system"))),
            encode_request(Start(relay(keys, "odd", parameters={"unknown": 1}))),
            json.dumps({"op": "start", "spec": {**good.as_dict(), "outputs": {"out": "a/*"}}}),
        ],
        "malformed_request": [
            None,
            b"{not json",
            b"\xff\xfe\xfd",
            b"[" * 50_000 + b"]" * 50_000,
            json.dumps({"op": ["start"]}),
            json.dumps({"op": "stop", "instance": 7}),
            json.dumps({"op": "stop", "instance": "../x"}),
            json.dumps({"op": "start", "spec": [good.as_dict()]}),
            json.dumps({"op": "status", "verbose": True}),
        ],
        "oversized_request": [b"{" + b" " * (2 * MAX_MESSAGE_BYTES) + b"}"],
    }
    for error, payloads in refused.items():
        for payload in payloads:
            ok, answer = hub.ask("lab", payload)
            assert not ok and answer["error"] == error, (payload[:80] if payload else None, answer)
    status = hub.status("lab")
    assert status["counters"]["refused_specs"] == 3
    assert status["counters"]["malformed_requests"] == 9
    assert status["counters"]["oversized_requests"] == 1
    assert status["instances"] == {}
    assert "started_cold" not in status["counters"]  # nothing refused ever ran

    # Still alive and serving.
    ok, started = hub.ask("lab", encode_request(Start(good)))
    assert ok, started
    wait_until(lambda: fetch_latest(hub.session, keys.status("good"), timeout=0.5), timeout=20)


def test_an_agent_without_a_host_manager_waits_for_one_then_serves(net):
    agent = net.agent("--no-host")
    net.tracker()
    relation = Relation(net.session, net.keys, RelationId("WT", "HT", "6D"), application="app")
    wait_until(lambda: (net.agent_status() or {}).get("components"), timeout=20)
    time.sleep(2.0)  # settled: it would have started workers by now
    status = net.agent_status()
    assert status["hosts"] == []
    assert not any(c["alive"] for c in status["components"].values())
    assert relation.latest() is None

    net.host("separate", 1, "-m", "ubitrack_agent.cli", "host")
    wait_until(lambda: relation.latest() is not None, timeout=30)
    status = net.agent_status()
    assert status["hosts"] == ["separate"]
    assert {c["host"] for c in status["components"].values()} == {"separate"}
    assert set(net.status("separate")["instances"]) == set(status["components"])

    # A clean stop of the agent leaves its workers running (for the agent started again) and
    # the host manager serving.
    running = net.status("separate")["instances"]
    agent.send_signal(signal.SIGTERM)
    assert agent.wait(timeout=15) == 0
    relation.wait_for(timeout=10)
    assert net.status("separate")["instances"] == running
    relation.close()


def test_workers_killed_before_and_after_their_token_are_started_again(net):
    net.agent("--no-host")
    net.host("lab", pool_size=0)  # cold starts: time to kill a worker before its token
    tokens = net.tokens()
    net.tracker()
    relation = Relation(net.session, net.keys, RelationId("WT", "HT", "6D"), application="app")
    instances = wait_until(lambda: net.status("lab")["instances"], timeout=20)
    victim, process = next(iter(instances.items()))
    os.kill(process["pid"], signal.SIGKILL)
    killed_at = time.monotonic()
    assert not [event for event in tokens if event[1] == victim]  # it never declared a token
    wait_until(lambda: relation.latest() is not None, timeout=30)
    assert next(e for e in tokens if e[1] == victim)[2] > killed_at
    # its container was restored by the host manager, which told the agent
    assert net.agent_status()["counters"]["restored"] >= 1
    assert net.status("lab")["counters"]["containers_restored"] >= 1

    # Killed while running: its host manager restores it, the agent rewires it.
    pid = net.status("lab")["instances"][victim]["pid"]
    os.kill(pid, signal.SIGKILL)

    def new_pid() -> int | None:
        replies = fetch_latest(net.session, net.keys.status(victim), timeout=0.5)
        found = json.loads(replies[0])["pid"] if replies else None
        return found if found not in (None, pid) else None

    wait_until(new_pid, timeout=30)
    relation.close()


def test_the_agent_starts_its_host_manager_again_which_adopts_and_restores_the_orphans(net):
    """Its host manager SIGKILLed, the agent's container serves on (it was its client and
    reaches the network through the hub); the host manager the agent starts again adopts it
    (its components are placed there again, none restarted), and restores it when it is
    killed in turn, the relation flowing again. With ``--stop-host-on-exit`` a clean stop
    then ends every worker and the host manager."""
    agent = net.agent("--stop-host-on-exit")  # with its own host manager
    net.tracker()
    relation = Relation(net.session, net.keys, RelationId("WT", "HT", "6D"), application="app")
    wait_until(lambda: relation.latest() is not None, timeout=30)
    (name,) = net.agent_status()["hosts"]
    first = net.status(name)["pid"]
    components = set(net.agent_status()["components"])

    os.kill(first, signal.SIGKILL)
    wait_until(  # the new host manager's start: 10 s seen at a load of 16
        lambda: net.ask(name, encode_request(Status()))[1].get("pid") not in (None, first), 30
    )
    relation.wait_for(timeout=10)  # still flowing
    host = wait_until(
        lambda: net.status(name)["counters"].get("containers_adopted") and net.status(name),
        timeout=20,
    )
    assert set(host["instances"]) == components
    (container,) = host["containers"].values()

    def placed_again() -> bool:  # the agent found them in the new host manager's status
        status = net.agent_status() or {"components": {"-": {"host": None}}}
        return all(c["host"] == name and c["alive"] for c in status["components"].values())

    wait_until(placed_again, timeout=20)
    status = net.agent_status()
    assert set(status["components"]) == components
    assert status["counters"].get("restarts", 0) == 0  # none restarted
    assert {c["pid"] for c in status["components"].values()} == {container["pid"]}

    os.kill(container["pid"], signal.SIGKILL)  # its adopter restores it, the agent rewires
    restored = wait_until(
        lambda: net.status(name)["counters"].get("containers_restored") and net.status(name),
        timeout=20,
    )
    (again,) = restored["containers"].values()
    assert again["pid"] != container["pid"] and set(restored["instances"]) == components
    wait_until(lambda: net.agent_status()["counters"].get("restored", 0) >= len(components), 20)
    relation.wait_for(timeout=20)  # flows again
    relation.wait_for(timeout=5)
    status = net.agent_status()
    assert status["counters"].get("restarts", 0) == 0  # restored in place, not started again
    assert {c["pid"] for c in status["components"].values()} == {again["pid"]}

    agent.send_signal(signal.SIGTERM)
    assert agent.wait(timeout=20) == 0
    wait_until(lambda: not workers(net.domain), timeout=10)
    relation.close()


def test_a_clean_agent_stop_leaves_its_host_manager_and_workers_serving_the_next_agent(net):
    """``ubitrack agent`` stopped cleanly (SIGTERM) stops no data: its workers and its host
    manager serve on, and the agent started again adopts both, every component in the
    process it ran in."""
    agent = net.agent()
    net.tracker()
    relation = Relation(net.session, net.keys, RelationId("WT", "HT", "6D"), application="app")
    wait_until(lambda: relation.latest() is not None, timeout=30)
    (name,) = net.agent_status()["hosts"]
    wait_until(lambda: all(c["host"] == name for c in net.agent_status()["components"].values()))
    before = net.status(name)
    pids = {i: c["pid"] for i, c in before["instances"].items()}

    agent.send_signal(signal.SIGTERM)
    assert agent.wait(timeout=20) == 0
    for _ in range(3):
        relation.wait_for(timeout=5)  # no agent: the data goes on
    host = net.status(name)
    assert host["pid"] == before["pid"] and host["orphaned"]
    assert {i: c["pid"] for i, c in host["instances"].items()} == pids

    net.agent()
    wait_until(lambda: net.agent_status()["counters"].get("adopted", 0) == len(pids), timeout=20)
    status = net.agent_status()
    assert all(c["alive"] for c in status["components"].values())
    assert status["counters"].get("restarts", 0) == 0
    host = net.status(name)
    assert host["pid"] == before["pid"]  # adopted, with its components
    assert {i: c["pid"] for i, c in host["instances"].items()} == pids
    relation.wait_for(timeout=5)
    relation.close()


def workers(domain: str) -> list[str]:
    """Host managers and workers of the test's domain still running."""
    return [pid for pid in tagged(domain) if "-m ubitrack_agent.services." in command_line(pid)]


def command_line(pid: str) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as file:
            return file.read().replace(b"\0", b" ").decode()
    except OSError:
        return ""
