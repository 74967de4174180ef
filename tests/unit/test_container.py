"""Containers (issue 28): groups in the specification, local wires handing over objects, and a
container of components on a stand-in session: hand-over without zenoh, add and remove in the
running process, rebinding when a producer joins or leaves, rejected commands, a faulty
component counted and restarted while the others go on."""

from __future__ import annotations

import contextlib
import json
import threading
import time
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from tests.unit.test_worker_inputs import KEYS, FakeSession
from ubitrack_agent.core import ErrorPose, Pose, Position3D, decode, encode
from ubitrack_agent.core.poses import compose_poses
from ubitrack_agent.net.spec import (
    ComponentSpec,
    GroupSpec,
    InputBinding,
    LocalWire,
    SpecError,
    parse_group,
)
from ubitrack_agent.services.container import RESTART_AFTER_FAULTS, Container
from ubitrack_agent.services.local_wires import LocalWires, deliver, finite
from ubitrack_agent.services.worker import RUN_MIN

RNG = np.random.default_rng(28)


def concatenation(instance: str, first: str, second: str, static_first: bool = True):
    """``instance`` composing a static ``first`` with a triggering ``second``."""
    return ComponentSpec(
        instance=instance,
        service="concatenation",
        inputs=(
            InputBinding("AB", KEYS.data(first), static=static_first),
            InputBinding("BC", KEYS.data(second), trigger=True, from_worker="/" in second),
        ),
        outputs={"AC": KEYS.data(f"{instance}/AC")},
    )


FIRST = concatenation("first", "ART/WT", "ART/HT")
SECOND = concatenation("second", "CAL/X", "first/AC")


def random_pose(t_ns: int) -> Pose:
    return Pose(t_ns, Rotation.random(rng=RNG).as_quat(), RNG.normal(size=3))


# -- groups in the specification --------------------------------------------------------------


def test_a_group_round_trips_and_names_its_wires():
    group = GroupSpec("c0", (FIRST, SECOND))
    assert parse_group(group.to_json()) == group
    assert group.wires == (LocalWire("first", "AC", "second", 1),)
    assert GroupSpec("c0", (SECOND,)).wires == ()


@pytest.mark.parametrize(
    "data, field",
    [
        ({"container": "c0", "components": [], "extra": 1}, "unknown fields"),
        ({"components": []}, "group.container: missing"),
        ({"container": "a/b", "components": []}, "group.container"),
        ({"container": "c0", "components": {}}, "expected a list"),
        ({"container": "c0", "components": [1]}, "components[0]: expected an object"),
        ({"container": "c0", "components": [{"instance": "x"}]}, "components[0]: spec"),
        ({"container": "c0", "components": [FIRST.as_dict()] * 2}, "'first' twice"),
    ],
)
def test_a_malformed_group_is_refused_naming_the_field(data, field):
    with pytest.raises(SpecError, match=field.replace("[", r"\[").replace("]", r"\]")):
        parse_group(json.dumps(data))


def test_two_components_of_a_group_may_publish_on_one_key_but_names_are_unique():
    clash = {**SECOND.as_dict(), "outputs": {"AC": KEYS.data("first/AC")}}
    group = parse_group({"container": "c0", "components": [FIRST.as_dict(), clash]})
    assert len(group.components) == 2
    with pytest.raises(SpecError, match="'first' twice"):
        parse_group({"container": "c0", "components": [FIRST.as_dict(), FIRST.as_dict()]})


@settings(max_examples=200, deadline=None)
@given(
    st.recursive(
        st.none() | st.booleans() | st.integers() | st.text(max_size=8),
        lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner),
        max_leaves=20,
    )
)
def test_parsing_a_group_is_total(value):
    for data in (value, {"container": "c0", "components": value}):
        with contextlib.suppress(SpecError):
            parse_group(json.dumps(data))


# -- local wires ------------------------------------------------------------------------------


def test_a_hand_over_waits_for_its_delivery_and_reaches_every_reader_in_order():
    wires = LocalWires()
    moved: list[set[str]] = []
    wires.changed = moved.append
    wires.produce("p", ("k",))
    got_a, got_b = [], []
    wires.subscribe("k", got_a.extend)
    subscription = wires.subscribe("k", got_b.extend)
    first, second = random_pose(1), random_pose(2)
    queued: list = []
    wires.hand_over("k", wires.readers["k"], first, queued)
    wires.hand_over("k", wires.readers["k"], second, queued)
    assert got_a == [] and wires.latest("k") is second
    deliver(queued)
    assert got_a == [first, second] and got_b == [first, second]
    assert got_a[0] is first  # the object itself: nothing encoded or copied
    subscription.undeclare()
    deliver([(wires.readers["k"], first)])
    assert len(got_b) == 2 and len(got_a) == 3
    wires.produce("p", ())
    assert moved == [{"k"}, {"k"}] and wires.producer("k") is None and wires.latest("k") is None


def test_consecutive_values_of_one_reader_arrive_in_one_call_and_the_order_is_kept():
    wires = LocalWires()
    calls: list[tuple[str, list[int]]] = []
    for name in ("a", "b"):
        wires.subscribe(
            name, lambda values, n=name: calls.append((n, [v.timestamp_ns for v in values]))
        )
    queued: list = []
    for key, t in (("a", 1), ("a", 2), ("b", 3), ("a", 4)):
        wires.hand_over(key, wires.readers[key], random_pose(t), queued)
    deliver(queued)
    assert calls == [("a", [1, 2]), ("b", [3]), ("a", [4])]


def test_a_readers_own_hand_over_is_delivered_by_the_reader_on_the_same_thread():
    wires = LocalWires()
    seen: list[tuple[str, int]] = []

    def relay(values):
        queued: list = []
        for value in values:
            seen.append(("mid", value.timestamp_ns))
            wires.hand_over("out", wires.readers["out"], value, queued)
        deliver(queued)

    wires.subscribe("in", relay)
    wires.subscribe("out", lambda values: seen.extend(("end", v.timestamp_ns) for v in values))
    deliver([(wires.readers["in"], random_pose(5))])
    assert seen == [("mid", 5), ("end", 5)]


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from(("produce", "reads")),
            st.sampled_from("abc"),
            st.sets(st.sampled_from(("k1", "k2", "k3", "k4"))),
        ),
        max_size=30,
    )
)
def test_the_wires_know_each_keys_producers_and_readers_as_a_search_of_all_would(steps):
    """``LocalWires.produce`` and ``reads`` keep their indexes by instance and by key (an add
    O(its own keys), not O(the container)): after any steps, the keys told as moved, the
    producer and the readers of each key are those found by searching every instance."""
    wires = LocalWires()
    moved: list[set[str]] = []
    wires.changed = moved.append
    produced: dict[str, set[str]] = {}
    read: dict[str, set[str]] = {}
    for kind, instance, keys in steps:
        if kind == "reads":
            wires.reads(instance, keys)
            read[instance] = set(keys)
        else:
            before = {key for owned in produced.values() for key in owned}
            wires.produce(instance, tuple(keys))
            produced[instance] = set(keys)
            after = {key for owned in produced.values() for key in owned}
            told = moved.pop() if before != after else set()
            assert told == before ^ after and moved == []
        for key in ("k1", "k2", "k3", "k4"):
            owners = [name for name, owned in sorted(produced.items()) if key in owned]
            assert wires.producer(key) == (owners[0] if owners else None)
            assert wires.reading({key}) == {name for name, keys in read.items() if key in keys}
    everything = {"k1", "k2", "k3", "k4"}
    assert wires.reading(everything) == {name for name, keys in read.items() if keys}


def test_finite_refuses_nan_and_infinity_in_any_field():
    good = ErrorPose(1, [0, 0, 0, 1], [1, 2, 3], np.eye(6) * 1e-6)
    assert finite(good)
    for name, bad in (("translation", [1, np.nan, 3]), ("covariance", np.full((6, 6), np.inf))):
        value = good.__class__.__new__(good.__class__)  # bypass validation, as a bug would
        object.__setattr__(value, "__dict__", {**good.__dict__, name: np.asarray(bad, float)})
        assert not finite(value)
    strided = np.eye(12)[::2, ::2]  # a view exporting no plain buffer: copied to be read
    for cell, expected in ((0.5, True), (np.inf, False), (np.nan, False)):
        strided[10 // 2, 2 // 2] = cell  # in the view
        value = good.__class__.__new__(good.__class__)
        object.__setattr__(value, "__dict__", {**good.__dict__, "covariance": strided})
        assert finite(value) is expected
    huge = ErrorPose(1, [0, 0, 0, 1], [1e308, -1e308, 0], np.eye(6))  # read number by number
    assert finite(huge)
    for cell in (-np.inf, -np.nan, np.float64(5e303) * 4, -np.float64(5e303) * 4):
        value = huge.__class__.__new__(huge.__class__)
        translation = np.array([1.0, cell, 0.0])
        object.__setattr__(value, "__dict__", {**huge.__dict__, "translation": translation})
        assert finite(value) is bool(np.isfinite(cell))
    point = Position3D(1, [1.0, 2.0, 3.0])  # an optional field left out
    assert finite(point) and finite(Position3D(1, [1.0, 2.0, 3.0], np.eye(3)))
    bad_point = Position3D.__new__(Position3D)
    object.__setattr__(
        bad_point, "__dict__", {**point.__dict__, "position": np.array([np.inf, 0, 0])}
    )
    assert not finite(bad_point)


# -- a container on a stand-in session ---------------------------------------------------------


class MatchingSession(FakeSession):
    """A stand-in session whose publishers report a subscriber outside the process (zenoh's
    matching status, told to their matching listeners) for every key but those in
    :attr:`quiet`, until :meth:`listen` is called for one."""

    def __init__(self) -> None:
        super().__init__()
        self.quiet: set[str] = {KEYS.data("first/AC")}
        self.listeners: dict[str, list] = {}
        self.scheduler = None

    def deliver(self, key: str, payload: bytes, wait: bool = True) -> None:
        """As zenoh delivers; a sample taken by a callback (a static input's, a command) is
        handled on the container's scheduler (``ubitrack_agent.services.scheduler``): waited for
        too."""
        super().deliver(key, payload, wait)
        if wait and self.scheduler is not None and key not in self.channels:
            done = threading.Event()
            self.scheduler.call(done.set)
            assert done.wait(5)

    def listen(self, key: str) -> None:
        """A subscriber outside the process appears on ``key``."""
        self.quiet.discard(key)
        for callback in self.listeners.get(key, ()):
            callback(SimpleNamespace(matching=True))

    def declare_publisher(self, key, encoding=None, congestion_control=None):
        session = self

        class Publisher:
            @property
            def matching_status(self):
                return SimpleNamespace(matching=key not in session.quiet)

            def declare_matching_listener(self, callback):
                session.listeners.setdefault(key, []).append(callback)
                return SimpleNamespace(undeclare=lambda: session.listeners[key].remove(callback))

            def put(self, data, attachment=None):
                session.puts.append((key, data))

            def undeclare(self):
                pass

        return Publisher()


def wait_for(condition, timeout: float = 5.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if value := condition():
            return value
        time.sleep(0.005)
    raise AssertionError("condition not met in time")


@pytest.fixture
def running():
    """A container running on its own thread over a stand-in session; ended after the test."""
    session = MatchingSession()
    container = Container(session, KEYS, "c0")
    session.scheduler = container.scheduler
    thread = threading.Thread(target=container.run, daemon=True)
    thread.start()
    yield container, session
    container.stop()
    thread.join(timeout=5)
    assert not thread.is_alive()


def control(session: FakeSession, command: dict) -> None:
    session.deliver(KEYS.control("c0"), json.dumps(command).encode())


def puts(session: FakeSession, key: str) -> list:
    return [decode(data) for k, data in session.puts if k == KEYS.data(key)]


def test_components_in_one_container_hand_over_objects_and_zenoh_carries_only_the_outside(
    running,
):
    container, session = running
    control(session, {"add": [FIRST.as_dict(), SECOND.as_dict()]})
    wait_for(lambda: len(container.components) == 2)
    assert KEYS.data("first/AC") not in session.channels  # read in the process, not subscribed
    static, calibration = random_pose(1_000), random_pose(1_000)
    session.deliver(KEYS.data("ART/WT"), encode(static))
    session.deliver(KEYS.data("CAL/X"), encode(calibration))
    moving = [random_pose(2_000 + i) for i in range(3)]
    for sample in moving:
        session.deliver(KEYS.data("ART/HT"), encode(sample))
    out = puts(session, "second/AC")
    assert [value.timestamp_ns for value in out] == [2_000, 2_001, 2_002]
    for value, sample in zip(out, moving, strict=True):
        want = compose_poses(calibration, compose_poses(static, sample))
        np.testing.assert_allclose(value.translation, want.translation, atol=1e-12)
    first = container.components["first"].worker
    assert first.counters["published"] == 3 and puts(session, "first/AC") == []
    assert first.status()["container"] == "c0"
    # A subscriber outside appears: the latest value is sent, and the next ones are put.
    session.listen(KEYS.data("first/AC"))
    wait_for(lambda: puts(session, "first/AC"))
    assert puts(session, "first/AC")[-1].timestamp_ns == 2_002
    session.deliver(KEYS.data("ART/HT"), encode(random_pose(3_000)))
    assert puts(session, "first/AC")[-1].timestamp_ns == 3_000
    assert puts(session, "second/AC")[-1].timestamp_ns == 3_000


def test_a_backlog_taken_as_a_run_is_handed_on_as_a_run_and_computed_as_each_alone(running):
    """A burst of at least ``RUN_MIN`` samples the first component takes as one run reaches
    the second as one run too (``LocalWires.flush``, ``Worker._on_value_run``), with the
    results, in order, that each sample alone gives."""
    container, session = running
    control(session, {"add": [FIRST.as_dict(), SECOND.as_dict()]})
    wait_for(lambda: len(container.components) == 2)
    static, calibration = random_pose(1_000), random_pose(1_000)
    session.deliver(KEYS.data("ART/WT"), encode(static))
    session.deliver(KEYS.data("CAL/X"), encode(calibration))
    moving = [random_pose(2_000 + i) for i in range(2 * RUN_MIN)]
    session.deliver_burst(KEYS.data("ART/HT"), [encode(sample) for sample in moving])
    out = puts(session, "second/AC")
    assert [value.timestamp_ns for value in out] == [sample.timestamp_ns for sample in moving]
    for value, sample in zip(out, moving, strict=True):
        want = compose_poses(calibration, compose_poses(static, sample))
        np.testing.assert_allclose(value.rotation, want.rotation, atol=1e-12)
        np.testing.assert_allclose(value.translation, want.translation, atol=1e-12)
    second = container.components["second"].worker
    assert second.counters["in_runs"] == len(moving) == second.counters["published"]
    assert container.components["first"].worker.counters["in_runs"] == len(moving)


def test_adding_a_producer_moves_its_reader_onto_the_local_wire_and_removing_it_moves_it_back(
    running,
):
    container, session = running
    control(session, {"add": [SECOND.as_dict()]})
    wait_for(lambda: KEYS.data("first/AC") in session.channels)  # over zenoh: no producer here
    control(session, {"add": [FIRST.as_dict()]})
    wait_for(lambda: container.counters["rebinds"] == 1)
    assert KEYS.data("first/AC") not in session.channels and container.counters["added"] == 2
    session.deliver(KEYS.data("CAL/X"), encode(random_pose(1)))
    session.deliver(KEYS.data("ART/WT"), encode(random_pose(1)))
    session.deliver(KEYS.data("ART/HT"), encode(random_pose(10)))
    assert [value.timestamp_ns for value in puts(session, "second/AC")] == [10]
    control(session, {"remove": ["first"]})
    wait_for(lambda: KEYS.data("first/AC") in session.channels)
    assert set(container.components) == {"second"} and container.counters["removed"] == 1
    session.deliver(KEYS.data("first/AC"), encode(random_pose(20)))  # from elsewhere now
    assert [value.timestamp_ns for value in puts(session, "second/AC")] == [10, 20]


def test_a_component_rewired_onto_a_key_is_bound_locally_when_its_producer_joins(running):
    """The container finds the readers of a key whose producer joined by the key
    (``LocalWires.reading``), kept as a component is rewired on its own control key."""
    container, session = running
    control(session, {"add": [SECOND.as_dict()]})
    wait_for(lambda: KEYS.data("first/AC") in session.channels)
    rewired = concatenation("second", "CAL/X", "third/AC")
    inputs = [binding.as_dict() for binding in rewired.inputs]
    session.deliver(KEYS.control("second"), json.dumps({"inputs": inputs}).encode())
    wait_for(lambda: KEYS.data("third/AC") in session.channels)
    assert KEYS.data("first/AC") not in session.channels
    control(session, {"add": [FIRST.as_dict()]})  # produces first/AC: read by nobody now
    wait_for(lambda: container.counters["added"] == 2)
    assert container.counters["rebinds"] == 0
    control(session, {"add": [concatenation("third", "ART/WT", "ART/HT").as_dict()]})
    wait_for(lambda: container.counters["rebinds"] == 1)
    assert KEYS.data("third/AC") not in session.channels
    session.deliver(KEYS.data("CAL/X"), encode(random_pose(1)))
    session.deliver(KEYS.data("ART/WT"), encode(random_pose(1)))
    session.deliver(KEYS.data("ART/HT"), encode(random_pose(10)))
    assert [value.timestamp_ns for value in puts(session, "second/AC")] == [10]


@pytest.mark.parametrize(
    "command",
    [
        b"{not json",
        json.dumps({"add": [{"instance": "x"}]}).encode(),
        json.dumps({"add": [{**FIRST.as_dict(), "service": "nope"}]}).encode(),
        json.dumps({"add": [FIRST.as_dict(), FIRST.as_dict()]}).encode(),
        json.dumps({"remove": "first"}).encode(),
        json.dumps({"remove": ["a/b"]}).encode(),
        json.dumps({"stop": 1}).encode(),
        json.dumps({"add": [], "remove": []}).encode(),
        json.dumps({"launch": []}).encode(),
    ],
)
def test_a_bad_container_command_is_refused_counted_and_changes_nothing(running, command):
    container, session = running
    control(session, {"add": [FIRST.as_dict()]})
    wait_for(lambda: container.components)
    session.deliver(KEYS.control("c0"), command)
    wait_for(lambda: container.counters["rejected_commands"] == 1)
    assert set(container.components) == {"first"} and container.counters["internal_errors"] == 0


def test_adding_a_component_already_running_is_refused(running):
    container, session = running
    control(session, {"add": [FIRST.as_dict()]})
    wait_for(lambda: container.components)
    control(session, {"add": [FIRST.as_dict(), SECOND.as_dict()]})
    wait_for(lambda: container.counters["rejected_commands"] == 1)
    assert set(container.components) == {"first"}  # all or none


def test_a_faulty_component_is_counted_and_restarted_while_the_other_goes_on(running):
    container, session = running
    control(session, {"add": [FIRST.as_dict(), SECOND.as_dict()]})
    wait_for(lambda: len(container.components) == 2)
    faulty = container.components["second"].worker

    def broken(values, timestamp_ns):
        raise RuntimeError("a bug in the service")

    faulty._service.compute = broken
    session.deliver(KEYS.data("ART/WT"), encode(random_pose(1)))
    session.deliver(KEYS.data("CAL/X"), encode(random_pose(1)))
    for i in range(RESTART_AFTER_FAULTS):
        session.deliver(KEYS.data("ART/HT"), encode(random_pose(100 + i)))
    first = container.components["first"].worker
    assert first.counters["published"] == RESTART_AFTER_FAULTS  # the other went on
    assert faulty.counters["internal_errors"] == RESTART_AFTER_FAULTS
    restarted = wait_for(
        lambda: (entry := container.components.get("second")) and entry.restarts == 1 and entry
    )
    assert restarted.worker is not faulty and container.counters["restarts"] == 1
    assert container.status()["components"]["second"]["restarts"] == 1
    session.deliver(KEYS.data("CAL/X"), encode(random_pose(1)))
    session.deliver(KEYS.data("ART/HT"), encode(random_pose(500)))
    wait_for(lambda: puts(session, "second/AC"))
    assert puts(session, "second/AC")[-1].timestamp_ns == 500


def test_a_component_stopped_on_its_own_control_key_leaves_the_container(running):
    container, session = running
    control(session, {"add": [FIRST.as_dict(), SECOND.as_dict()]})
    wait_for(lambda: len(container.components) == 2)
    session.deliver(KEYS.control("second"), json.dumps({"stop": True}).encode())
    wait_for(lambda: set(container.components) == {"first"})
    assert container.counters["removed"] == 1 and container.counters["restarts"] == 0
    left = [json.loads(data) for k, data in session.puts if k == KEYS.container_left("c0")]
    assert [report["instances"] for report in left] == [["second"]]  # for its host manager
    assert left[0]["incarnation"] == container.incarnation and left[0]["reason"] == "released"


def test_a_static_output_computed_before_its_reader_joined_reaches_it(running):
    container, session = running
    inversion = ComponentSpec(
        instance="inv",
        service="inversion",
        inputs=(InputBinding("AB", KEYS.data("ART/WT"), trigger=True, static=True),),
        outputs={"BA": KEYS.data("inv/BA")},
    )
    control(session, {"add": [inversion.as_dict()]})
    wait_for(lambda: container.components)
    session.deliver(KEYS.data("ART/WT"), encode(random_pose(1)))
    wait_for(lambda: container.components["inv"].worker.counters["published"] == 1)
    reader = concatenation("reader", "inv/BA", "ART/HT")  # joins after the value was computed
    control(session, {"add": [reader.as_dict()]})
    wait_for(lambda: len(container.components) == 2)
    worker = container.components["reader"].worker
    wait_for(lambda: worker.counters["buffered"] == 1)  # the static value, handed at binding
    session.deliver(KEYS.data("ART/HT"), encode(random_pose(10)))
    assert [value.timestamp_ns for value in puts(session, "reader/AC")] == [10]


def test_a_container_whose_host_manager_is_gone_ends_with_its_last_component():
    session = MatchingSession()
    parent = SimpleNamespace(gone=False, serve=lambda declare: declare())
    container = Container(session, KEYS, "c0", components=(FIRST,), parent=parent)
    thread = threading.Thread(target=container.run, daemon=True)
    thread.start()
    parent.gone = True  # serving: it keeps running while it has a component
    time.sleep(0.2)
    assert thread.is_alive()
    control(session, {"remove": ["first"]})
    thread.join(timeout=5)
    assert not thread.is_alive() and container.components == {}


def test_a_container_takes_commands_on_its_own_incarnation_s_key(running):
    container, session = running
    other = KEYS.control_incarnation("c0", "1.another")  # a process of the same name elsewhere
    assert other not in session.callbacks and KEYS.control("c0") in session.callbacks
    own = KEYS.control_incarnation("c0", container.incarnation)
    session.deliver(own, json.dumps({"add": [FIRST.as_dict()]}).encode())
    wait_for(lambda: set(container.components) == {"first"})


def test_while_a_plan_changes_two_producers_of_one_key_feed_its_reader_locally(running):
    """Two components of a group publishing on one key, as two processes may (the agent names
    each output after its component, so it never asks for it): the reader takes both."""
    container, session = running
    twin = replace(concatenation("twin", "ART/WT2", "ART/HT2"), outputs=FIRST.outputs)
    control(session, {"add": [FIRST.as_dict(), twin.as_dict(), SECOND.as_dict()]})
    wait_for(lambda: len(container.components) == 3)
    assert KEYS.data("first/AC") not in session.channels  # read in the process
    for key in ("ART/WT", "ART/WT2", "CAL/X"):  # (the stand-in session: one reader a key)
        session.deliver(KEYS.data(key), encode(random_pose(1)))
    session.deliver(KEYS.data("ART/HT"), encode(random_pose(10)))
    session.deliver(KEYS.data("ART/HT2"), encode(random_pose(20)))
    assert [value.timestamp_ns for value in puts(session, "second/AC")] == [10, 20]
    control(session, {"remove": ["first"]})  # the old producer goes: the reader stays local
    wait_for(lambda: set(container.components) == {"twin", "second"})
    assert container.counters["rebinds"] == 0 and KEYS.data("first/AC") not in session.channels
    session.deliver(KEYS.data("ART/HT2"), encode(random_pose(30)))
    assert [value.timestamp_ns for value in puts(session, "second/AC")] == [10, 20, 30]


def test_a_closed_component_handles_nothing_more_handed_to_it(running):
    container, session = running
    control(session, {"add": [FIRST.as_dict(), SECOND.as_dict()]})
    wait_for(lambda: len(container.components) == 2)
    session.deliver(KEYS.data("CAL/X"), encode(random_pose(1_000)))
    second = container.components["second"].worker
    trigger = [binding.key for binding in SECOND.inputs].index(KEYS.data("first/AC"))
    before = second.counters
    second._deliver_values(second._generation, trigger, [random_pose(2_000)])
    taken = second.counters
    assert taken["received"] == before["received"] + 1
    assert taken["published"] == before["published"] + 1
    second.close()  # as its container ends it: no stop() before
    second._deliver_values(second._generation, trigger, [random_pose(3_000)])
    assert second.counters == taken
