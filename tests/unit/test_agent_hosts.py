"""The agent's side of the host managers (``ubitrack_agent/agent/hosts.py``) on a stand-in
session: where starts go, when they wait, which exit reports restart what, how stops go."""

import json
from types import SimpleNamespace

import pytest

from ubitrack_agent.agent import hosts as hosts_module
from ubitrack_agent.agent.hosts import Hosts, Placement
from ubitrack_agent.agent.problems import Problems
from ubitrack_agent.net.clock import ClockEstimate
from ubitrack_agent.net.host_protocol import (
    STOP_COMMAND,
    Exited,
    HostInfo,
    ProtocolError,
    Started,
    Status,
    parse_request,
)
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.spec import ComponentSpec, InputBinding

KEYS = KeySpace("ubitrack/test")
PUT, DELETE = "SampleKind.PUT", "SampleKind.DELETE"


def payload(data: bytes) -> SimpleNamespace:
    return SimpleNamespace(to_bytes=lambda: data)


class FakeSession:
    """Records requests and puts; hosts answer with ``answers[host]`` (a callable, or None for
    silence)."""

    def __init__(self) -> None:
        self.callbacks: dict[str, object] = {}
        self.requests: list[tuple[str, object]] = []
        self.puts: list[tuple[str, str]] = []
        self.answers: dict[str, object] = {}
        self.status_requests: list[str] = []
        self.statuses: dict[str, object] = {}

    def liveliness(self):
        return SimpleNamespace(declare_subscriber=self._subscribe)

    def declare_subscriber(self, key, callback, history=False):
        return self._subscribe(key, callback, history)

    def _subscribe(self, key, callback, history=False):
        self.callbacks[key] = callback
        return SimpleNamespace(undeclare=lambda: None)

    def event(self, selector: str, kind: str, key: str, data: bytes = b"") -> None:
        self.callbacks[selector](SimpleNamespace(kind=kind, key_expr=key, payload=payload(data)))

    def get(self, key, payload=None, timeout=None, handler=None):
        host = KEYS.parse_host(key.removesuffix("/request"))
        request = parse_request(payload.encode())
        if handler is not None:  # a status request: the reply comes through the handler
            assert isinstance(request, Status)
            self.status_requests.append(host)
            if host in self.statuses:
                handler(self.statuses[host])
            return None
        self.requests.append((host, request))
        answer = self.answers.get(host)
        return [] if answer is None else [answer(request)]

    def put(self, key, data, **options):
        self.puts.append((key, data))


def started(request) -> SimpleNamespace:
    run = f"run-{request.spec.instance}"
    reply = Started(request.spec.instance, run, 7, reused=False).to_json().encode()
    return SimpleNamespace(ok=SimpleNamespace(payload=payload(reply)), err=None)


def refused(request) -> SimpleNamespace:
    reply = ProtocolError("refused_spec", "no").to_json().encode()
    return SimpleNamespace(ok=None, err=SimpleNamespace(payload=payload(reply)))


def stopped(request) -> SimpleNamespace:
    reply = json.dumps({"instance": request.instance, "process": "released"}).encode()
    return SimpleNamespace(ok=SimpleNamespace(payload=payload(reply)), err=None)


@pytest.fixture
def clock(monkeypatch):
    now = [10.0]
    monkeypatch.setattr(hosts_module.time, "monotonic", lambda: now[0])
    return now


@pytest.fixture
def world(clock):
    session, problems = FakeSession(), Problems()
    return session, Hosts(session, KEYS, problems), problems.counters


def host_appears(session: FakeSession, hosts: Hosts, name: str) -> None:
    session.event(KEYS.all_hosts(), PUT, KEYS.host(name))
    assert hosts.reap(set()) == []


def spec(instance: str) -> ComponentSpec:
    return ComponentSpec(
        instance=instance,
        service="relay",
        inputs=(InputBinding("in", KEYS.data("art/HT"), trigger=True),),
        outputs={"out": KEYS.data(f"{instance}/out")},
    )


def test_a_start_goes_to_the_chosen_live_host_manager(world):
    session, hosts, _counters = world
    assert hosts.available() == {}
    assert not hosts.start(spec("a"), "alpha")
    assert session.requests == []
    for name in ("zeta", "alpha"):
        session.answers[name] = started
        host_appears(session, hosts, name)
    assert hosts.available() == {"alpha": HostInfo("alpha"), "zeta": HostInfo("zeta")}
    assert not hosts.start(spec("a"), "nowhere")
    assert hosts.start(spec("a"), "zeta")
    assert [host for host, _ in session.requests] == ["zeta"]
    assert hosts.placements["a"] == Placement("zeta", "run-a")
    assert hosts.reports_exit_of("a")


def status_reply(data: dict) -> SimpleNamespace:
    return SimpleNamespace(ok=SimpleNamespace(payload=payload(json.dumps(data).encode())))


def test_host_information_is_asked_when_a_host_appears_and_then_now_and_then(world, clock):
    session, hosts, counters = world
    estimate = ClockEstimate(-200_000_000, 100_000, 200_000, 8)
    info = HostInfo("hmd", frozenset({"camera"}), 8, 0.5, estimate)
    running = {"relay-x": {"service": "relay", "run": "r1", "pid": 9, "pool_id": None}}
    session.statuses["hmd"] = status_reply({**info.as_dict(), "pid": 1, "instances": running})
    host_appears(session, hosts, "hmd")
    hosts.reap(set())  # the reply was queued by the handler
    assert session.status_requests == ["hmd"]
    assert hosts.available() == {"hmd": info}
    # A worker it runs that the agent had no placement for (adopted, say) now has one.
    assert hosts.placements == {"relay-x": Placement("hmd", "r1", 9)}
    assert hosts.reap(set()) == [] and session.status_requests == ["hmd"]  # not due yet
    clock[0] += hosts_module.INFO_REFRESH_S + 0.1
    session.statuses["hmd"] = status_reply({**info.as_dict(), "name": "room"})
    hosts.reap(set())
    hosts.reap(set())
    assert session.status_requests == ["hmd", "hmd"]
    assert counters["rejected_host_reports"] == 1  # it named another host: ignored
    assert hosts.available() == {"hmd": info}  # the last good information is kept
    clock[0] += hosts_module.INFO_REFRESH_S + 0.1
    session.statuses["hmd"] = status_reply({"name": "hmd", "labels": "camera"})
    hosts.reap(set())
    hosts.reap(set())
    assert counters["rejected_host_reports"] == 2
    session.event(KEYS.all_hosts(), DELETE, KEYS.host("hmd"))
    hosts.reap(set())
    assert hosts.available() == {} and hosts.info == {}
    # Its clock is kept (the machine may still run its sensors), less certain as it ages.
    kept = hosts.clocks()["hmd"]
    assert kept.offset_ns == estimate.offset_ns
    assert kept.uncertainty_ns > estimate.uncertainty_ns


def test_refused_and_unanswered_starts_are_asked_again_later(world, clock):
    session, hosts, counters = world
    session.answers["lab"] = refused
    host_appears(session, hosts, "lab")
    assert not hosts.start(spec("a"), "lab")
    assert not hosts.start(spec("a"), "lab")  # not again at once
    assert len(session.requests) == 1
    clock[0] += hosts_module.START_RETRY_S + 0.1
    session.answers["lab"] = None  # silent
    assert not hosts.start(spec("a"), "lab")
    assert not hosts.start(spec("b"), "lab")  # a silent host manager is left alone for a while
    assert len(session.requests) == 2
    clock[0] += hosts_module.START_RETRY_S + 0.1
    session.answers["lab"] = started
    assert hosts.start(spec("a"), "lab") and hosts.start(spec("b"), "lab")
    assert counters["refused_starts"] == 2


def zenoh_timeout(request) -> SimpleNamespace:
    """What zenoh itself replies when a queryable does not answer in time."""
    return SimpleNamespace(ok=None, err=SimpleNamespace(payload=payload(b"Timeout")))


def test_a_zenoh_error_reply_is_no_answer_and_the_host_is_left_alone(world, clock):
    session, hosts, counters = world
    session.answers["lab"] = zenoh_timeout
    host_appears(session, hosts, "lab")
    assert not hosts.start(spec("a"), "lab")
    assert hosts.available() == {}  # silent for a while: nothing else is sent to it
    assert not hosts.start(spec("b"), "lab") and len(session.requests) == 1
    assert counters["refused_starts"] == 1
    assert hosts._problems.last["refused_starts"].endswith("no answer (Timeout)")
    clock[0] += hosts_module.START_RETRY_S + 0.1
    session.answers["lab"] = started
    assert set(hosts.available()) == {"lab"} and hosts.start(spec("b"), "lab")


def test_only_a_matching_exit_report_restarts(world):
    session, hosts, counters = world
    session.answers["lab"] = started
    host_appears(session, hosts, "lab")
    hosts.start(spec("a"), "lab")
    exits = KEYS.all_host_exits()
    for report in (
        Exited("a", "an-earlier-run", 1, 0, "exited"),  # stale
        Exited("b", "run-b", 1, 0, "exited"),  # not ours
    ):
        session.event(exits, PUT, KEYS.host_exited("lab"), report.to_json().encode())
    session.event(exits, PUT, KEYS.host_exited("other"), b"{garbage")
    session.event(exits, PUT, KEYS.host_exited("lab") + "/extra", b"{}")
    assert hosts.reap(set()) == []
    assert counters["rejected_host_reports"] == 1  # the garbage payload
    assert counters["rejected_host_exited_keys"] == 1  # the key with a chunk too many
    report = Exited("a", "run-a", 1, -9, "exited")
    session.event(exits, PUT, KEYS.host_exited("lab"), report.to_json().encode())
    assert hosts.reap({"a"}) == ["a"]
    assert "a" not in hosts.placements


def test_a_vanished_host_manager_restarts_its_instances_that_are_not_alive(world):
    session, hosts, _counters = world
    session.answers["lab"] = started
    host_appears(session, hosts, "lab")
    hosts.start(spec("a"), "lab")
    hosts.start(spec("b"), "lab")
    session.event(KEYS.all_hosts(), DELETE, KEYS.host("lab"))
    assert hosts.reap(alive={"a"}) == ["b"]
    assert hosts.placements == {}
    assert not hosts.reports_exit_of("a")  # now watched by its worker token


def test_stops_go_through_the_host_manager_else_on_the_control_key(world):
    session, hosts, _counters = world
    session.answers["lab"] = started
    host_appears(session, hosts, "lab")
    hosts.start(spec("a"), "lab")
    session.answers["lab"] = stopped
    hosts.stop("a")
    assert session.requests[-1][0] == "lab" and session.puts == []
    hosts.stop("adopted")  # never placed: the stop command itself
    assert session.puts == [(KEYS.control("adopted"), STOP_COMMAND)]
