"""The host manager's process handling (``services/supervisor.py``) with stand-in processes:
the warm pool, starting without duplicates, releases, exits and overdue stops."""

import json
from collections import Counter

import pytest

from ubitrack_agent.net.host_protocol import STOP_COMMAND, ProtocolError
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.spec import ComponentSpec, GroupSpec, InputBinding
from ubitrack_agent.services import supervisor as supervisor_module
from ubitrack_agent.services.adoption import UNKNOWN_EXIT, LocalWorker, Orphan
from ubitrack_agent.services.supervisor import Supervisor

KEYS = KeySpace("ubitrack/test")


class FakeProcess:
    """Enough of ``subprocess.Popen`` for the supervisor."""

    next_pid = 1000

    def __init__(self, arguments: tuple[str, ...]) -> None:
        FakeProcess.next_pid += 1
        self.pid = FakeProcess.next_pid
        self.arguments = arguments
        self.returncode: int | None = None
        self.signals: list[str] = []

    def poll(self) -> int | None:
        return self.returncode

    def terminate(self) -> None:
        self.signals.append("TERM")

    def kill(self) -> None:
        self.signals.append("KILL")
        self.returncode = -9

    def wait(self, timeout: float | None = None) -> int:
        self.returncode = -15 if self.returncode is None else self.returncode
        return self.returncode


class FakeSession:
    def __init__(self) -> None:
        self.puts: list[tuple[str, str]] = []

    def put(self, key: str, payload: str, **_options: object) -> None:
        self.puts.append((key, payload))


@pytest.fixture
def clock(monkeypatch):
    now = [100.0]
    monkeypatch.setattr(supervisor_module.time, "monotonic", lambda: now[0])
    return now


@pytest.fixture
def make(monkeypatch):
    def build(pool_size: int) -> tuple[Supervisor, FakeSession, list[FakeProcess]]:
        session, spawned = FakeSession(), []

        def spawn(self, pool_id, *arguments):
            spawned.append(FakeProcess((pool_id, *arguments)))
            return spawned[-1]

        monkeypatch.setattr(Supervisor, "_spawn", spawn)
        return Supervisor(session, KEYS, [], pool_size, Counter()), session, spawned

    return build


def spec(instance: str, source: str = "art/HT") -> ComponentSpec:
    return ComponentSpec(
        instance=instance,
        service="relay",
        inputs=(InputBinding("in", KEYS.data(source), trigger=True),),
        outputs={"out": KEYS.data(f"{instance}/out")},
    )


def ready_pool(supervisor: Supervisor, spawned: list[FakeProcess], clock) -> str:
    """Fill one pool member and announce its token; its pool id."""
    supervisor.fill_pool()
    pool_id = spawned[-1].arguments[0]
    supervisor.on_pool_token(pool_id, appeared=True)
    return pool_id


def test_pool_fills_one_at_a_time_after_a_quiet_period(make, clock):
    supervisor, _, spawned = make(pool_size=2)
    supervisor.fill_pool()
    supervisor.fill_pool()
    assert len(spawned) == 1  # the first is still starting
    supervisor.on_pool_token(spawned[0].arguments[0], appeared=True)
    supervisor.start(spec("a"))  # takes the ready member
    supervisor.fill_pool()
    assert len(spawned) == 1  # not quiet yet
    clock[0] += supervisor_module.REFILL_QUIET_S + 0.1
    supervisor.fill_pool()
    assert len(spawned) == 2


def test_start_uses_a_ready_member_else_a_fresh_process(make, clock):
    supervisor, session, spawned = make(pool_size=1)
    pool_id = ready_pool(supervisor, spawned, clock)
    warm = supervisor.start(spec("a"))
    assert session.puts == [(KEYS.pool(pool_id), spec("a").to_json())]
    assert warm.pid == spawned[0].pid and not warm.reused
    cold = supervisor.start(spec("b"))
    assert spawned[1].arguments[1:] == ("--spec", spec("b").to_json())
    assert cold.pid == spawned[1].pid
    assert supervisor.counters["started_from_pool"] == supervisor.counters["started_cold"] == 1


def test_a_repeated_start_starts_nothing_and_a_changed_one_replaces(make, clock):
    supervisor, session, spawned = make(pool_size=0)
    first = supervisor.start(spec("a"))
    again = supervisor.start(spec("a"))
    assert again.reused and (again.run, again.pid) == (first.run, first.pid)
    assert len(spawned) == 1
    replaced = supervisor.start(spec("a", source="ir/HT"))
    assert len(spawned) == 2 and replaced.run != first.run
    assert spawned[0].signals == ["TERM"]  # the old one is stopped (pool full at size 0)
    assert (KEYS.control("a"), STOP_COMMAND) in session.puts


def test_stop_releases_to_the_pool_or_terminates(make, clock):
    supervisor, session, spawned = make(pool_size=1)
    supervisor.start(spec("a"))
    supervisor.start(spec("b"))
    assert supervisor.stop("a") == "released"  # the pool is short: back to it
    assert supervisor.stop("b") == "terminated"  # now full
    assert supervisor.stop("c") == "none"
    assert [key for key, _ in session.puts] == [KEYS.control(i) for i in "abc"]
    assert spawned[1].signals == ["TERM"]
    released = spawned[0].arguments[0]
    supervisor.on_pool_token(released, appeared=True)
    assert supervisor.status()["pool_ready"] == 1


def test_a_released_member_that_does_not_rejoin_is_terminated_then_killed(make, clock):
    supervisor, _, spawned = make(pool_size=1)
    supervisor.start(spec("a"))
    supervisor.stop("a")
    clock[0] += supervisor_module.STOP_GRACE_S + 0.1
    supervisor.reap()
    assert spawned[0].signals == ["TERM"]
    clock[0] += supervisor_module.STOP_GRACE_S + 0.1
    supervisor.reap()
    assert spawned[0].signals == ["TERM", "KILL"]
    assert supervisor.counters["killed"] == 1


def test_a_stop_is_put_again_until_the_process_confirms_it(make, clock):
    """A process still starting misses a stop put before it subscribed: the stop is put again
    until its pool token shows it ended its run; only then is it a pool member."""
    supervisor, session, spawned = make(pool_size=1)
    supervisor.start(spec("a"))
    supervisor.stop("a")
    assert supervisor.status()["releasing"] == 1 and supervisor.status()["pool_ready"] == 0
    for _ in range(3):
        clock[0] += supervisor_module.STOP_RESEND_S + 0.01
        supervisor.reap()
    assert session.puts.count((KEYS.control("a"), STOP_COMMAND)) == 4
    supervisor.on_pool_token(spawned[0].arguments[0], appeared=True)
    assert supervisor.status()["releasing"] == 0 and supervisor.status()["pool_ready"] == 1
    assert supervisor.counters["stops_confirmed"] == 1 and spawned[0].signals == []


def test_starting_an_instance_again_terminates_its_releasing_process(make, clock):
    supervisor, session, spawned = make(pool_size=2)
    supervisor.start(spec("a"))
    supervisor.stop("a")
    supervisor.start(spec("a"))  # wanted again before the first process confirmed its stop
    assert spawned[0].signals == ["TERM"] and len(spawned) == 2
    clock[0] += supervisor_module.STOP_RESEND_S + 0.01
    supervisor.reap()
    assert session.puts.count((KEYS.control("a"), STOP_COMMAND)) == 1  # none for the new one


def test_a_member_that_never_gets_ready_is_terminated_and_the_pool_refills(make, clock):
    supervisor, _, spawned = make(pool_size=1)
    supervisor.fill_pool()
    clock[0] += supervisor_module.POOL_READY_S + 0.1
    supervisor.reap()
    assert spawned[0].signals == ["TERM"]
    supervisor.fill_pool()
    assert len(spawned) == 2


def test_exits_and_releases_from_elsewhere_are_reported(make, clock):
    supervisor, _, spawned = make(pool_size=1)
    a = supervisor.start(spec("a"))
    b = supervisor.start(spec("b"))
    spawned[0].returncode = -9  # killed before it ever declared its token
    (exited,) = supervisor.reap()
    assert (exited.instance, exited.run, exited.returncode, exited.reason) == (
        "a",
        a.run,
        -9,
        "exited",
    )
    # Someone else's stop command released b: its pool token appears.
    released = supervisor.on_pool_token(spawned[1].arguments[0], appeared=True)
    assert (released.instance, released.run, released.reason) == ("b", b.run, "released")
    assert supervisor.assigned == {}
    assert supervisor.status()["pool_ready"] == 1
    assert supervisor.on_pool_token("other-host-member", appeared=True) is None


def test_terminate_all_ends_every_process(make, clock):
    supervisor, _, spawned = make(pool_size=1)
    ready_pool(supervisor, spawned, clock)
    supervisor.start(spec("a"))
    supervisor.start(spec("b"))
    supervisor.terminate_all()
    assert all(process.returncode is not None for process in spawned)
    assert supervisor.status()["instances"] == {}


# -- containers (issue 28) -----------------------------------------------------------------------


def commands(session: FakeSession, key: str) -> list[dict]:
    return [json.loads(payload) for k, payload in session.puts if k == key]


def container_ready(supervisor: Supervisor, name: str) -> str:
    """Announce the token of container ``name``'s process; the key it takes commands on."""
    box = supervisor.containers[name]
    supervisor.on_container_token(name, f"{box.process.pid + 1}.x", appeared=True)  # not its
    assert box.incarnation is None
    supervisor.on_container_token(name, f"{box.process.pid}.x", appeared=True)
    assert box.incarnation == f"{box.process.pid}.x"
    return KEYS.control_incarnation(name, box.incarnation)


def test_a_group_starts_a_container_from_the_pool_and_later_ones_are_added(make, clock):
    supervisor, session, spawned = make(pool_size=1)
    pool_id = ready_pool(supervisor, spawned, clock)
    first = supervisor.start_group(GroupSpec("lab-0", (spec("a"), spec("b"))))
    assert first.pid == spawned[0].pid and [s.instance for s in first.started] == ["a", "b"]
    assert commands(session, KEYS.pool(pool_id)) == [
        GroupSpec("lab-0", (spec("a"), spec("b"))).as_dict()
    ]
    # the container is not taking commands yet: an add waits for its token
    later = supervisor.start_group(GroupSpec("lab-0", (spec("a"), spec("c"))))
    assert [(s.instance, s.reused) for s in later.started] == [("a", True), ("c", False)]
    assert not [key for key, _ in session.puts if key.startswith(KEYS.control("lab-0"))]
    control = container_ready(supervisor, "lab-0")
    assert commands(session, control) == [{"add": [spec("c").as_dict()]}]
    assert len(spawned) == 1  # no process started for the add
    status = supervisor.status()
    assert status["instances"]["c"]["container"] == "lab-0"
    assert status["containers"] == {"lab-0": {"pid": spawned[0].pid, "ready": True}}


def test_a_cold_container_is_given_its_group_once_its_pool_token_is_up(make, clock):
    supervisor, session, spawned = make(pool_size=0)
    supervisor.start_group(GroupSpec("lab-0", (spec("a"),)))
    assert len(spawned) == 1 and spawned[0].arguments[1:] == ()  # a pool member, no spec
    pool_id = spawned[0].arguments[0]
    assert commands(session, KEYS.pool(pool_id)) == []
    supervisor.on_pool_token(pool_id, appeared=True)
    assert commands(session, KEYS.pool(pool_id)) == [GroupSpec("lab-0", (spec("a"),)).as_dict()]
    supervisor.on_pool_token(pool_id, appeared=True)  # again: given once
    assert len(commands(session, KEYS.pool(pool_id))) == 1


def test_a_container_goes_to_a_member_still_starting_rather_than_a_new_process(make, clock):
    supervisor, session, spawned = make(pool_size=1)
    supervisor.fill_pool()  # importing: no pool token yet
    supervisor.start_group(GroupSpec("lab-0", (spec("a"),)))
    assert len(spawned) == 1  # no second cold process competing with the first
    pool_id = spawned[0].arguments[0]
    supervisor.on_pool_token(pool_id, appeared=True)
    assert commands(session, KEYS.pool(pool_id)) == [GroupSpec("lab-0", (spec("a"),)).as_dict()]
    assert supervisor.counters["containers_from_starting_members"] == 1
    assert supervisor.status()["pool_starting"] == 0  # it is the container now, no member


def test_stops_remove_components_and_an_empty_container_ends(make, clock):
    supervisor, session, spawned = make(pool_size=0)
    supervisor.start_group(GroupSpec("lab-0", (spec("a"), spec("b"))))
    control = container_ready(supervisor, "lab-0")
    assert supervisor.stop("a") == "removed"
    assert commands(session, control) == [{"remove": ["a"]}]
    assert KEYS.control("a") not in {k for k, _ in session.puts}
    supervisor.stop("b")
    supervisor.start_group(GroupSpec("lab-0", (spec("b", source="ir/HT"),)))  # b restarted
    supervisor.reap()
    clock[0] += supervisor_module.EMPTY_GRACE_S + 1
    supervisor.reap()
    assert "lab-0" in supervisor.containers  # b runs in it again
    supervisor.stop("b")
    supervisor.reap()
    clock[0] += supervisor_module.EMPTY_GRACE_S + 1
    supervisor.reap()
    assert supervisor.containers == {}
    assert commands(session, control)[-1] == {"stop": True}
    clock[0] += supervisor_module.STOP_GRACE_S + 1
    supervisor.reap()
    assert spawned[0].signals == ["KILL"]  # it did not end: killed


def test_a_component_moves_between_containers_of_the_host(make, clock):
    supervisor, session, _spawned = make(pool_size=0)
    supervisor.start_group(GroupSpec("lab-0", (spec("a"), spec("b"))))
    supervisor.start_group(GroupSpec("lab-1", (spec("c"),)))
    old, new = container_ready(supervisor, "lab-0"), container_ready(supervisor, "lab-1")
    moved = supervisor.start_group(GroupSpec("lab-1", (spec("a"),)))
    assert not moved.started[0].reused and supervisor.assigned["a"].container == "lab-1"
    assert commands(session, old) == [{"remove": ["a"]}]
    assert commands(session, new) == [{"add": [spec("a").as_dict()]}]


def test_a_dead_container_is_restored_with_its_components_until_it_dies_too_quickly(make, clock):
    supervisor, session, spawned = make(pool_size=0)
    runs = {
        s.instance: s.run
        for s in supervisor.start_group(GroupSpec("lab-0", (spec("a"), spec("b")))).started
    }
    container_ready(supervisor, "lab-0")
    clock[0] += supervisor_module.QUICK_RESTORE_S + 1
    spawned[0].returncode = -9
    exits = supervisor.reap()
    assert [(e.instance, e.run, e.pid, e.reason) for e in exits] == [
        ("a", runs["a"], spawned[1].pid, "restored"),
        ("b", runs["b"], spawned[1].pid, "restored"),
    ]
    supervisor.on_pool_token(spawned[1].arguments[0], appeared=True)
    group = commands(session, KEYS.pool(spawned[1].arguments[0]))
    assert [c["instance"] for c in group[0]["components"]] == ["a", "b"]
    assert supervisor.counters["containers_restored"] == 1
    for _ in range(supervisor_module.MAX_QUICK_RESTORES):  # each dies at once
        spawned[-1].returncode = 1
        assert {e.reason for e in supervisor.reap()} == {"restored"}
    spawned[-1].returncode = 1
    exits = supervisor.reap()
    assert {(e.instance, e.reason) for e in exits} == {("a", "exited"), ("b", "exited")}
    assert supervisor.assigned == {} and supervisor.containers == {}


def test_a_component_that_left_by_its_own_stop_is_reported_released(make, clock):
    supervisor, _session, spawned = make(pool_size=0)
    supervisor.start_group(GroupSpec("lab-0", (spec("a"), spec("b"))))
    pid = spawned[0].pid
    other = json.dumps({"instances": ["a"], "incarnation": f"{pid + 5}.x"}).encode()
    assert supervisor.on_left("lab-0", other) == []  # another process's
    report = json.dumps({"instances": ["a", "zzz"], "incarnation": f"{pid}.x"}).encode()
    exits = supervisor.on_left("lab-0", report)
    assert [(e.instance, e.reason, e.returncode) for e in exits] == [("a", "released", None)]
    assert set(supervisor.assigned) == {"b"}
    failed = json.dumps({"instances": ["b"], "incarnation": f"{pid}.x", "reason": "exited"})
    assert [(e.instance, e.reason) for e in supervisor.on_left("lab-0", failed.encode())] == [
        ("b", "exited")  # it failed to start there: the agent starts it again
    ]
    for bad in (
        b"{",
        b"[]",
        json.dumps({"instances": ["a/b"], "incarnation": f"{pid}.x"}).encode(),
        json.dumps({"instances": [], "incarnation": f"{pid}.x", "reason": "x"}).encode(),
    ):
        with pytest.raises(ProtocolError):
            supervisor.on_left("lab-0", bad)


class FakeAdopted(FakeProcess):
    """An adopted process (``services.adoption.AdoptedProcess``): ended when told."""

    instances: list["FakeAdopted"] = []

    def __init__(self, pid: int, started: int) -> None:
        super().__init__(())
        self.pid, self.started = pid, started
        FakeAdopted.instances.append(self)

    def end(self) -> None:
        self.returncode = UNKNOWN_EXIT


def test_an_adopted_container_is_run_as_if_started_here_and_restored_when_it_dies(
    make, clock, monkeypatch
):
    monkeypatch.setattr(supervisor_module, "AdoptedProcess", FakeAdopted)
    supervisor, session, spawned = make(pool_size=0)
    orphan = Orphan("lab-0", "4242.abcd", LocalWorker("old-pool", 77), (spec("a"), spec("b")))
    assert supervisor.adopt(orphan) == 2
    (process,) = FakeAdopted.instances[-1:]
    assert (process.pid, process.started) == (4242, 77)
    status = supervisor.status()
    assert status["containers"] == {"lab-0": {"pid": 4242, "ready": True}}
    assert {i: s["container"] for i, s in status["instances"].items()} == {
        "a": "lab-0",
        "b": "lab-0",
    }
    runs = {i: s["run"] for i, s in status["instances"].items()}
    assert supervisor.counters["containers_adopted"] == 1
    assert supervisor.knows_container("lab-0", 4242) and not supervisor.knows_container("lab-0", 1)

    # adopted again, or one of its components taken: left alone
    assert supervisor.adopt(orphan) == 0
    assert supervisor.counters["orphans_left"] == 1

    # commands reach this process alone; a stop removes a component
    assert supervisor.stop("b") == "removed"
    assert commands(session, KEYS.control_incarnation("lab-0", "4242.abcd")) == [{"remove": ["b"]}]

    process.end()  # dies: restored with what it ran, in a process of this supervisor's
    reports = supervisor.reap()
    assert [(r.instance, r.run, r.returncode, r.reason) for r in reports] == [
        ("a", runs["a"], None, "restored")
    ]
    assert reports[0].pid == spawned[-1].pid != 4242
    assert supervisor.counters["containers_restored"] == 1


def test_an_adopted_process_that_has_ended_is_not_adopted(make, clock, monkeypatch):
    class Gone(FakeAdopted):
        def poll(self) -> int | None:
            return UNKNOWN_EXIT

    monkeypatch.setattr(supervisor_module, "AdoptedProcess", Gone)
    supervisor, _, _ = make(pool_size=0)
    orphan = Orphan("lab-0", "4242.abcd", LocalWorker("old-pool", 77), (spec("a"),))
    assert supervisor.adopt(orphan) == 0
    assert supervisor.status()["instances"] == {}


# -- tokens awaited too long: asked for ------------------------------------------------------------


def test_a_container_token_awaited_too_long_is_asked_for_once_per_interval(make, clock):
    supervisor, session, spawned = make(pool_size=1)
    ready_pool(supervisor, spawned, clock)
    supervisor.start_group(GroupSpec("lab-0", (spec("a"),)))
    supervisor.start_group(GroupSpec("lab-0", (spec("a"), spec("b"))))  # an add, waiting
    assert supervisor.awaited_tokens(clock[0]) == []  # not awaited long yet
    clock[0] += supervisor_module.TOKEN_ASK_S + 0.1
    assert supervisor.awaited_tokens(clock[0]) == [("container", KEYS.all_containers())]
    assert supervisor.awaited_tokens(clock[0] + 1.0) == []  # asked within the interval
    box = supervisor.containers["lab-0"]
    supervisor.on_container_token_found("lab-0", f"{box.process.pid + 1}.x")  # another process
    assert box.incarnation is None and supervisor.counters["tokens_found"] == 0
    supervisor.on_container_token_found("lab-0", f"{box.process.pid}.x")
    assert box.incarnation == f"{box.process.pid}.x"
    assert supervisor.counters["tokens_found"] == 1
    control = KEYS.control_incarnation("lab-0", box.incarnation)
    assert commands(session, control) == [{"add": [spec("b").as_dict()]}]  # the add is sent
    supervisor.on_container_token_found("lab-0", f"{box.process.pid}.x")  # a later reply
    assert supervisor.counters["tokens_found"] == 1
    clock[0] += supervisor_module.POOL_READY_S  # ready: never terminated, nothing asked
    assert supervisor.reap() == [] and spawned[0].signals == []
    assert supervisor.awaited_tokens(clock[0]) == []


def test_a_pool_token_found_readies_only_a_member_still_awaited(make, clock):
    supervisor, _, spawned = make(pool_size=1)
    supervisor.fill_pool()
    pool_id = spawned[0].arguments[0]
    clock[0] += supervisor_module.TOKEN_ASK_S + 0.1
    assert supervisor.awaited_tokens(clock[0]) == [("pool", KEYS.all_pools())]
    supervisor.on_pool_token_found("other-host-member")
    assert supervisor.status()["pool_ready"] == 0
    supervisor.on_pool_token_found(pool_id)
    assert supervisor.status()["pool_ready"] == 1
    assert supervisor.counters["tokens_found"] == 1
    started = supervisor.start(spec("a"))  # takes the member
    assert started.pid == spawned[0].pid
    supervisor.on_pool_token_found(pool_id)  # a reply older than the start: not a release
    assert "a" in supervisor.assigned and supervisor.counters["released"] == 0


def test_a_cold_container_is_given_its_group_when_its_pool_token_is_found(make, clock):
    supervisor, session, spawned = make(pool_size=0)
    supervisor.start_group(GroupSpec("lab-0", (spec("a"),)))
    pool_id = spawned[0].arguments[0]
    clock[0] += supervisor_module.TOKEN_ASK_S + 0.1
    asked = supervisor.awaited_tokens(clock[0])
    assert ("pool", KEYS.all_pools()) in asked and ("container", KEYS.all_containers()) in asked
    supervisor.on_pool_token_found(pool_id)
    assert commands(session, KEYS.pool(pool_id)) == [GroupSpec("lab-0", (spec("a"),)).as_dict()]
    supervisor.on_pool_token_found(pool_id)  # again: given once, counted once
    assert len(commands(session, KEYS.pool(pool_id))) == 1
    assert supervisor.counters["tokens_found"] == 1
