"""The agent's side of the host managers (``ubitrack_agent/agent/hosts.py``) on a stand-in
session: where starts go, when they wait, which exit reports restart what, how stops go."""

import json
from dataclasses import replace
from types import SimpleNamespace

import pytest

from ubitrack_agent.agent import hosts as hosts_module
from ubitrack_agent.agent.hosts import Hosts, Placement
from ubitrack_agent.agent.problems import Problems
from ubitrack_agent.net.address import tag
from ubitrack_agent.net.clock import ClockEstimate
from ubitrack_agent.net.host_protocol import (
    MAX_MESSAGE_BYTES,
    STOP_COMMAND,
    Exited,
    HostInfo,
    ProtocolError,
    Started,
    StartedGroup,
    Status,
    encode_request,
    parse_request,
)
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.spec import ComponentSpec, GroupSpec, InputBinding

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

    def event(
        self, selector: str, kind: str, key: str, data: bytes = b"", put_on: str | None = None
    ) -> None:
        """A sample on ``key``, put there (or on ``put_on``: zenoh delivered it on ``key``)."""
        found = None if put_on is None else payload(tag(put_on))
        self.callbacks[selector](
            SimpleNamespace(kind=kind, key_expr=key, payload=payload(data), attachment=found)
        )

    def get(self, key, payload=None, timeout=None, handler=None):
        host = KEYS.parse_host(key.removesuffix("/request"))
        request = parse_request(payload.encode())
        if handler is not None and isinstance(request, Status):  # the reply: to the handler
            self.status_requests.append(host)
            if host in self.statuses:
                handler(self.statuses[host])
            return None
        if handler is not None:  # a stop of a clean stop: answered through the handler
            self.requests.append((host, request))
            if (answer := self.answers.get(host)) is not None:
                handler(answer(request))
            return None
        self.requests.append((host, request))
        answer = self.answers.get(host)
        return [] if answer is None else [answer(request)]

    def put(self, key, data, **options):
        self.puts.append((key, data))


def started(request) -> SimpleNamespace:
    group = request.group
    runs = tuple(Started(s.instance, f"run-{s.instance}", 7, False) for s in group.components)
    reply = StartedGroup(group.container, 7, runs).to_json().encode()
    return SimpleNamespace(ok=SimpleNamespace(payload=payload(reply), attachment=None), err=None)


def start(hosts: Hosts, component: ComponentSpec, host: str) -> bool:
    """Whether ``host`` started ``component`` alone in its first container."""
    return hosts.start_group(GroupSpec(f"{host}-0", (component,)), host) == [component.instance]


def refused(request) -> SimpleNamespace:
    reply = ProtocolError("refused_spec", "no").to_json().encode()
    return SimpleNamespace(ok=None, err=SimpleNamespace(payload=payload(reply)))


def stopped(request) -> SimpleNamespace:
    reply = json.dumps({"instance": request.instance, "process": "released"}).encode()
    return SimpleNamespace(ok=SimpleNamespace(payload=payload(reply), attachment=None), err=None)


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
    assert not start(hosts, spec("a"), "alpha")
    assert session.requests == []
    for name in ("zeta", "alpha"):
        session.answers[name] = started
        host_appears(session, hosts, name)
    assert hosts.available() == {"alpha": HostInfo("alpha"), "zeta": HostInfo("zeta")}
    assert not start(hosts, spec("a"), "nowhere")
    assert start(hosts, spec("a"), "zeta")
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
    assert not start(hosts, spec("a"), "lab")
    assert not start(hosts, spec("a"), "lab")  # not again at once
    assert len(session.requests) == 1
    clock[0] += hosts_module.START_RETRY_S + 0.1
    session.answers["lab"] = None  # silent
    assert not start(hosts, spec("a"), "lab")
    assert not start(hosts, spec("b"), "lab")  # a silent host manager is left alone for a while
    assert len(session.requests) == 2
    clock[0] += hosts_module.START_RETRY_S + 0.1
    session.answers["lab"] = started
    assert start(hosts, spec("a"), "lab") and start(hosts, spec("b"), "lab")
    assert counters["refused_starts"] == 2


def zenoh_timeout(request) -> SimpleNamespace:
    """What zenoh itself replies when a queryable does not answer in time."""
    return SimpleNamespace(ok=None, err=SimpleNamespace(payload=payload(b"Timeout")))


def test_a_zenoh_error_reply_is_no_answer_and_the_host_is_left_alone(world, clock):
    session, hosts, counters = world
    session.answers["lab"] = zenoh_timeout
    host_appears(session, hosts, "lab")
    assert not start(hosts, spec("a"), "lab")
    assert hosts.available() == {}  # silent for a while: nothing else is sent to it
    assert not start(hosts, spec("b"), "lab") and len(session.requests) == 1
    assert counters["refused_starts"] == 1
    assert hosts._problems.last["refused_starts"].endswith("no answer (Timeout)")
    clock[0] += hosts_module.START_RETRY_S + 0.1
    session.answers["lab"] = started
    assert set(hosts.available()) == {"lab"} and start(hosts, spec("b"), "lab")


def test_a_reply_put_on_another_key_is_no_answer(world, clock):
    """A host manager's reply whose attachment names another key than the request's
    (``net.address``: zenoh delivered it here) starts nothing."""
    session, hosts, _counters = world

    def misaddressed(request) -> SimpleNamespace:
        reply = started(request)
        reply.ok.attachment = payload(tag(KEYS.host_request("other")))
        reply.ok.key_expr = KEYS.host_request("lab")
        return reply

    session.answers["lab"] = misaddressed
    host_appears(session, hosts, "lab")
    assert not start(hosts, spec("a"), "lab") and "a" not in hosts.placements
    assert hosts._problems.last["refused_starts"].endswith(
        "a reply put on another key (net.address)"
    )
    clock[0] += hosts_module.START_RETRY_S + 0.1
    session.answers["lab"] = started
    assert start(hosts, spec("a"), "lab")


def test_a_vanished_token_ends_an_instance_its_host_manager_no_longer_lists(world, clock):
    """An exit report can be lost (a stop meant for another component, delivered to this one,
    reported on its container's key during a partition): when a placed instance's token
    vanishes its host manager is asked at once, and a status without the instance ends it;
    one that lists it, or its token back, does not."""
    session, hosts, counters = world
    session.answers["lab"] = started
    host_appears(session, hosts, "lab")
    for name in ("a", "b", "c"):
        start(hosts, spec(name), "lab")
    hosts.reap({"a", "b", "c"})
    asked = len(session.status_requests)

    def lab_runs(*instances: str) -> SimpleNamespace:
        running = {i: {"run": f"run-{i}", "pid": 7} for i in instances}
        return status_reply({**HostInfo("lab").as_dict(), "pid": 1, "instances": running})

    session.statuses["lab"] = lab_runs("b")  # a is gone, b still runs
    for name in ("a", "b", "c"):
        hosts.await_exit(name)
    assert hosts.reap({"c"}) == []  # c's token is back: not awaited; the status asked at once
    assert len(session.status_requests) == asked + 1
    assert hosts.reap({"c"}) == ["a"]  # the reply, queued by the handler
    assert "a" not in hosts.placements and hosts.placements["b"] == Placement("lab", "run-b", 7)
    assert counters["exits_unreported"] == 1
    clock[0] += hosts_module.INFO_REFRESH_S + 0.1
    session.statuses["lab"] = lab_runs()
    hosts.reap({"c"})
    assert hosts.reap({"c"}) == []  # b was listed, c came back: neither awaited any more
    assert counters["exits_unreported"] == 1


def test_only_a_matching_exit_report_restarts(world):
    session, hosts, counters = world
    session.answers["lab"] = started
    host_appears(session, hosts, "lab")
    start(hosts, spec("a"), "lab")
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
    # put on another host's key, delivered on lab's (net.address): refused
    put_on = KEYS.host_exited("other")
    session.event(exits, PUT, KEYS.host_exited("lab"), report.to_json().encode(), put_on)
    assert hosts.reap({"a"}) == [] and counters["misaddressed"] == 1
    session.event(exits, PUT, KEYS.host_exited("lab"), report.to_json().encode())
    assert hosts.reap({"a"}) == ["a"]
    assert "a" not in hosts.placements


def test_a_vanished_host_manager_restarts_its_instances_that_are_not_alive(world):
    session, hosts, _counters = world
    session.answers["lab"] = started
    host_appears(session, hosts, "lab")
    start(hosts, spec("a"), "lab")
    start(hosts, spec("b"), "lab")
    session.event(KEYS.all_hosts(), DELETE, KEYS.host("lab"))
    assert hosts.reap(alive={"a"}) == []
    assert hosts.take_lost() == ["b"] and hosts.take_lost() == []  # for the agent to restart
    assert hosts.placements == {}
    assert not hosts.reports_exit_of("a")  # now watched by its worker token


def test_stops_go_through_the_host_manager_else_on_the_control_key(world):
    session, hosts, _counters = world
    session.answers["lab"] = started
    host_appears(session, hosts, "lab")
    start(hosts, spec("a"), "lab")
    session.answers["lab"] = stopped
    hosts.stop("a")
    assert session.requests[-1][0] == "lab" and session.puts == []
    hosts.stop("adopted")  # never placed: the stop command itself
    assert session.puts == [(KEYS.control("adopted"), STOP_COMMAND)]


def test_a_clean_stop_sends_every_stop_at_once_and_waits_for_the_replies_together(
    world, monkeypatch
):
    """``stop_all``: one wait for every reply (``REQUEST_TIMEOUT_S`` in all); a stop that was
    refused, unanswered or had no host manager is put on the control key."""
    monkeypatch.setattr(hosts_module, "REQUEST_TIMEOUT_S", 0.05)
    session, hosts, counters = world
    for host in ("lab", "quiet", "picky"):
        session.answers[host] = started
        host_appears(session, hosts, host)
        start(hosts, spec(f"on-{host}"), host)
    start(hosts, spec("also-on-lab"), "lab")
    session.answers.update(lab=stopped, quiet=None, picky=refused)
    taken = hosts.stop_all(["on-lab", "also-on-lab", "on-quiet", "on-picky", "adopted"])
    assert taken == 2
    stops = [(host, r.instance) for host, r in session.requests if hasattr(r, "instance")]
    assert sorted(stops) == [
        ("lab", "also-on-lab"),
        ("lab", "on-lab"),
        ("picky", "on-picky"),
        ("quiet", "on-quiet"),
    ]
    assert sorted(key for key, _ in session.puts) == [
        KEYS.control("adopted"),
        KEYS.control("on-picky"),
        KEYS.control("on-quiet"),
    ]
    assert counters["failed_stops"] == 1  # the unanswered one
    assert hosts.placements == {}


def test_a_container_s_components_start_in_one_request_split_only_by_size(world):
    session, hosts, _counters = world
    session.answers["lab"] = started
    host_appears(session, hosts, "lab")
    three = tuple(spec(name) for name in ("a", "b", "c"))
    assert hosts.start_group(GroupSpec("lab-1", three), "lab") == ["a", "b", "c"]
    assert len(session.requests) == 1
    assert hosts.placements["b"] == Placement("lab", "run-b", 7, "lab-1")
    assert hosts.placements["b"].container == "lab-1"
    big = ComponentSpec(  # each about a fifth of the protocol's message size
        instance="x",
        service="relay",
        inputs=(InputBinding("in", KEYS.data("art/HT"), trigger=True),),
        outputs={"out": KEYS.data("x/out")},
        parameters={"padding": "p" * (MAX_MESSAGE_BYTES // 5)},
    )
    many = tuple(
        replace(big, instance=f"x{i}", outputs={"out": KEYS.data(f"x{i}")}) for i in range(5)
    )
    assert hosts.start_group(GroupSpec("lab-0", many), "lab") == [s.instance for s in many]
    sizes = [len(r.group.components) for _, r in session.requests[1:]]
    assert sizes == [2, 2, 1]
    assert all(len(encode_request(r)) < MAX_MESSAGE_BYTES for _, r in session.requests)


def test_a_restored_container_keeps_its_components_placed_and_lists_them(world):
    session, hosts, _counters = world
    session.answers["lab"] = started
    host_appears(session, hosts, "lab")
    hosts.start_group(GroupSpec("lab-0", (spec("a"), spec("b"))), "lab")
    exits = KEYS.all_host_exits()
    for instance in ("a", "b"):
        report = Exited(instance, f"run-{instance}", 99, -9, "restored")
        session.event(exits, PUT, KEYS.host_exited("lab"), report.to_json().encode())
    stale = Exited("a", "an-earlier-run", 98, -9, "restored")
    session.event(exits, PUT, KEYS.host_exited("lab"), stale.to_json().encode())
    assert hosts.reap({"a", "b"}) == []  # nothing to start again
    assert hosts.restored == {"a": 99, "b": 99}
    assert hosts.placements["a"].pid == 99 and hosts.reports_exit_of("a")


def test_the_container_of_a_component_whose_host_manager_is_gone_comes_from_its_token(world):
    """A component adopted in a container whose host manager died (no placement) is recorded
    in that container: the process of one of its incarnations runs it (its container token)."""
    session, hosts, counters = world
    session.answers["lab"] = started
    host_appears(session, hosts, "lab")
    start(hosts, spec("a"), "lab")
    assert hosts.container_of("a", ["7.aaaa"]) == "lab-0"  # placed: the start's reply says
    session.event(KEYS.all_hosts(), DELETE, KEYS.host("lab"))
    session.event(KEYS.all_containers(), PUT, KEYS.container("lab-0", "7.cccc"))
    session.event(KEYS.all_containers(), PUT, KEYS.container("other-0", "9.dddd"))
    session.event(KEYS.all_containers(), PUT, "ubitrack/test/container/a b/1.x")
    hosts.reap(alive={"a"})
    assert hosts.placements == {}
    assert hosts.container_of("a", ["7.aaaa"]) == "lab-0"
    assert hosts.container_of("b", ["8.bbbb"]) is None  # a process of its own
    assert counters["rejected_container_keys"] == 1
    session.event(KEYS.all_containers(), DELETE, KEYS.container("lab-0", "7.cccc"))
    hosts.reap(alive={"a"})
    assert hosts.container_of("a", ["7.aaaa"]) is None
