"""The lean data path of issue 12: validation levels, results taken in one pass, the Cholesky
test for positive semi-definite covariances, the cached adjoint and scalar quaternion paths,
the inbox drained in one go, each input's samples handled on its own thread in bursts and
runs, and the races of the worker's lock."""

from __future__ import annotations

import dataclasses
import json
import threading
import time
from types import SimpleNamespace

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from tests.unit.test_worker_inputs import (
    IDENTITY,
    KEYS,
    SPEC,
    FakeSession,
    outputs,
    pose,
    zenoh_sample,
)
from ubitrack_agent.core import (
    ErrorPose,
    MeasurementError,
    Pose,
    decode,
    encode,
    poses,
    quaternions,
)
from ubitrack_agent.core.measurements import (
    DERIVED,
    FULL,
    WORKER,
    _positive_definite,
    _positive_definite_by_numpy,
    check_covariance,
    check_semidefinite,
)
from ubitrack_agent.core.poses import compose_pose_pairs, compose_poses
from ubitrack_agent.core.uncertainty import adjoint
from ubitrack_agent.net.spec import InputBinding, SpecError, parse_bindings
from ubitrack_agent.services.worker import RUN_MIN, Inbox, Worker

COVARIANCE = np.eye(6) * 1e-6


def error_pose_message(**fields: object) -> bytes:
    message = msgpack.unpackb(encode(ErrorPose(1, IDENTITY, [0.0, 1.0, 0.0], COVARIANCE)))
    message.update(fields)
    return msgpack.packb(message)


# -- validation levels ------------------------------------------------------------------------


def test_a_worker_sample_skips_what_holds_by_construction_only():
    skewed = np.array(IDENTITY) * 1.01  # not a unit quaternion
    payload = error_pose_message(rotation=skewed.tobytes())
    with pytest.raises(MeasurementError, match="unit quaternion"):
        decode(payload, ErrorPose, FULL)
    assert decode(payload, ErrorPose, WORKER).rotation[3] == pytest.approx(1.01)


@pytest.mark.parametrize("level", [FULL, WORKER])
def test_samples_from_outside_or_a_worker_with_nan_are_refused(level):
    nan = np.array([0.0, np.nan, 0.0])
    with pytest.raises(MeasurementError, match="translation: contains NaN"):
        decode(error_pose_message(translation=nan.tobytes()), ErrorPose, level)


@pytest.mark.parametrize("level", [FULL, WORKER, DERIVED])
def test_every_level_refuses_wrong_shapes(level):
    with pytest.raises(MeasurementError, match="do not fit"):
        decode(error_pose_message(translation=np.zeros(6).tobytes()), ErrorPose, level)
    with pytest.raises(MeasurementError, match="shape must be 3"):
        ErrorPose.checked(
            level, timestamp_ns=1, rotation=IDENTITY, translation=np.zeros(4), covariance=COVARIANCE
        )


def test_a_result_holding_nan_is_refused_where_it_leaves_the_process():
    """The maths' results are checked by the encoder (level DERIVED checks shapes only)."""
    degenerate = ErrorPose.derived(
        timestamp_ns=1,
        rotation=np.array(IDENTITY),
        translation=np.array([np.inf, 0.0, 0.0]),
        covariance=COVARIANCE.copy(),
    )
    with pytest.raises(MeasurementError, match="NaN or infinity"):
        encode(degenerate)


def test_a_worker_counts_a_result_it_cannot_publish():
    session = FakeSession()
    worker = worker_with_static(session, 1_000)
    huge = 1.5e308  # finite, but the sum of two overflows to infinity
    session.deliver(KEYS.data("ART/WT"), encode(Pose(1_500, IDENTITY, [huge, 0.0, 0.0])))
    session.deliver(KEYS.data("ART/HT"), encode(Pose(2_000, IDENTITY, [huge, 0.0, 0.0])))
    worker.step(longest_s=0.0)
    assert outputs(session) == []
    assert worker.counters["failed"] == 1 and worker.counters["internal_errors"] == 0
    worker.stop()


@pytest.mark.parametrize("level", [FULL, WORKER])
def test_an_indefinite_covariance_is_refused_from_a_worker_too(level):
    indefinite = COVARIANCE.copy()
    indefinite[0, 0] = -1e-3
    with pytest.raises(MeasurementError, match="not positive semi-definite"):
        decode(error_pose_message(covariance=indefinite.tobytes()), ErrorPose, level)


def test_a_singular_covariance_passes_the_cholesky_test():
    exact = np.zeros((6, 6))
    exact[3:, 3:] = np.eye(3) * 1e-6  # an exact rotation: positive semi-definite, singular
    assert decode(error_pose_message(covariance=exact.tobytes()), ErrorPose, WORKER)


@settings(max_examples=300, deadline=None)
@given(
    st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6),
    st.integers(0, 2**32 - 1),
)
def test_the_cholesky_test_decides_as_the_eigenvalues_do(eigenvalues, seed):
    """Random symmetric matrices with eigenvalues around zero (some just below the
    tolerance, some just above): refused exactly when the smallest eigenvalue is below
    -1e-9 times the scale."""
    basis = Rotation.random(rng=np.random.default_rng(seed)).as_matrix()
    rotation = np.kron(np.eye(2), basis)  # orthonormal 6x6
    values = np.array(eigenvalues) * np.array([1, 1e-6, 1e-9, 1e-10, 1e-12, 1e-3])
    matrix = rotation @ np.diag(values) @ rotation.T
    matrix = 0.5 * (matrix + matrix.T)
    smallest = np.linalg.eigvalsh(matrix)[0]
    for check, scale in (
        (check_semidefinite, max(1.0, np.trace(matrix))),
        (check_covariance, max(1.0, np.abs(matrix).max())),
    ):
        if abs(smallest + 1e-9 * scale) < 1e-12:
            continue  # at the boundary round-off decides either way
        if smallest < -1e-9 * scale:
            with pytest.raises(MeasurementError):
                check("c", matrix)
        else:
            check("c", matrix)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6), st.integers(0, 2**32 - 1))
def test_lapack_and_numpy_decide_positive_definiteness_alike(eigenvalues, seed):
    """The worker's Cholesky (LAPACK's dpotrf, SciPy loaded) and the agent's (numpy's)."""
    basis = np.kron(np.eye(2), Rotation.random(rng=np.random.default_rng(seed)).as_matrix())
    matrix = basis @ np.diag(np.array(eigenvalues) * 1e-6) @ basis.T
    matrix = 0.5 * (matrix + matrix.T)
    if abs(np.linalg.eigvalsh(matrix)[0]) < 1e-18:
        return  # at the boundary round-off decides either way
    assert _positive_definite()(matrix) == _positive_definite_by_numpy(matrix)
    assert _positive_definite_by_numpy(matrix) == (np.linalg.eigvalsh(matrix)[0] > 0)


@pytest.mark.parametrize(
    "fields",
    [
        {"translation": np.zeros(4)},  # a wrong shape
        {"translation": [0.0, 1.0]},  # no array, and a wrong length
        {"covariance": None},  # a required field missing
    ],
)
def test_a_result_that_is_not_the_maths_arrays_is_checked_in_full_at_its_level(fields):
    """``derived`` takes only float64 arrays of the declared shapes in one pass; anything
    else goes through ``checked`` at level DERIVED, which names what is wrong."""
    values = {"rotation": np.array(IDENTITY), "translation": np.zeros(3), "covariance": COVARIANCE}
    with pytest.raises(MeasurementError, match="ErrorPose"):
        ErrorPose.derived(timestamp_ns=1, **{**values, **fields})


def test_a_result_given_as_other_numbers_is_converted_to_float64_arrays():
    result = Pose.derived(timestamp_ns=1, rotation=np.array([0, 0, 0, 1]), translation=[1, 2, 3])
    assert result.rotation.dtype == np.float64 and result.translation.tolist() == [1.0, 2.0, 3.0]
    assert not result.rotation.flags.writeable and not result.translation.flags.writeable


def test_a_result_keeps_the_maths_arrays_made_read_only():
    """Level DERIVED takes the new arrays of the maths as they are (no copy) and freezes them;
    the constructor (level FULL) copies a caller's arrays instead."""
    rotation, covariance = np.array(IDENTITY), COVARIANCE.copy()
    result = ErrorPose.derived(
        timestamp_ns=1, rotation=rotation, translation=np.zeros(3), covariance=covariance
    )
    assert result.rotation is rotation and not rotation.flags.writeable
    given = np.array(IDENTITY)
    built = ErrorPose(1, given, np.zeros(3), COVARIANCE)
    given[0] = 5.0
    assert built.rotation[0] == 0.0 and not built.covariance.flags.writeable


# -- maths on single poses -------------------------------------------------------------------


def test_scalar_quaternion_paths_equal_the_batched_ones():
    q = Rotation.random(50, rng=np.random.default_rng(3)).as_quat()
    batched_products = quaternions.multiply(q[:-1], q[1:])
    batched_matrices = quaternions.to_matrix(q)
    for i in range(49):
        np.testing.assert_allclose(
            quaternions.multiply(q[i], q[i + 1]), batched_products[i], atol=1e-15
        )
        np.testing.assert_allclose(quaternions.to_matrix(q[i]), batched_matrices[i], atol=1e-15)
    v = np.random.default_rng(5).normal(size=(50, 3))
    batched_rotated = quaternions.rotate(q, v)
    for i in range(50):
        rotated = quaternions.rotate_floats(q[i].tolist(), v[i].tolist())
        np.testing.assert_allclose(rotated, batched_rotated[i], atol=1e-14)


def test_what_depends_on_a_static_input_is_computed_once():
    q = Rotation.random(rng=np.random.default_rng(4)).as_quat()
    static = ErrorPose(5, q, [0.1, -2.0, 0.3], np.eye(6) * 1e-6)
    q1, t1, first, transposed = poses._kept(static)
    again = poses._kept(static.restamped(99))  # a restamped one shares its arrays
    assert again[0] is q1 and again[1] is t1 and again[2] is first
    assert q1 == static.rotation.tolist() and t1 == static.translation.tolist()
    np.testing.assert_array_equal(first, adjoint(static.rotation, static.translation))
    np.testing.assert_array_equal(transposed, first.T)
    assert not first.flags.writeable and not transposed.flags.writeable
    twin = ErrorPose(5, q, [0.1, -2.0, 0.3], np.eye(6) * 1e-6)  # equal, other arrays
    assert poses._kept(twin)[2] is not first
    np.testing.assert_array_equal(poses._kept(twin)[2], first)


def test_the_poses_kept_are_forgotten_at_once_when_full():
    kept = [Pose(1, [0, 0, 0, 1], [float(i), 0, 0]) for i in range(poses._KEPT_POSES + 3)]
    for value in kept:
        np.testing.assert_array_equal(
            poses._kept(value)[2], adjoint(value.rotation, value.translation)
        )
    assert 0 < len(poses._KEPT) <= poses._KEPT_POSES


def test_a_composition_is_read_only_float64_of_the_types_shapes():
    """``compose_poses`` builds its result unchecked (``Measurement.unchecked``): what the
    validating constructor would have made of the same numbers, read-only."""
    rng = np.random.default_rng(8)
    a = rng.normal(size=(6, 6)) * 1e-2
    first = ErrorPose(3, Rotation.random(rng=rng).as_quat(), [1.0, 2.0, 3.0], a @ a.T)
    second = Pose(7, Rotation.random(rng=rng).as_quat(), [0.5, -0.5, 0.25])
    for result in (compose_poses(first, second), compose_poses(second, first)):
        assert type(result) is ErrorPose and result.timestamp_ns == 7
        checked = ErrorPose(7, result.rotation, result.translation, result.covariance)
        assert checked == result
        for array in (result.rotation, result.translation, result.covariance):
            assert array.dtype == np.float64 and not array.flags.writeable
    plain = compose_poses(first.mean(), second)
    assert type(plain) is Pose and plain == Pose(7, plain.rotation, plain.translation)
    assert not plain.rotation.flags.writeable and not plain.translation.flags.writeable


# -- input bindings ----------------------------------------------------------------------------


def test_from_worker_is_written_when_set_and_reads_back():
    binding = InputBinding("BC", KEYS.data("c1/AC"), trigger=True, from_worker=True)
    assert binding.as_dict()["from_worker"] is True
    assert "from_worker" not in InputBinding("BC", KEYS.data("p/e"), trigger=True).as_dict()
    assert parse_bindings([binding.as_dict()]) == (binding,)


@pytest.mark.parametrize("value", [1, "true", None, [True]])
def test_from_worker_must_be_a_boolean(value):
    raw = {"port": "BC", "key": KEYS.data("c1/AC"), "trigger": True, "from_worker": value}
    with pytest.raises(SpecError, match="from_worker"):
        parse_bindings([raw])


# -- inbox and hand-off ------------------------------------------------------------------------


def test_the_inbox_drains_in_order_and_counts_what_it_drops():
    counters: dict[str, int] = {"overflow": 0}
    inbox = Inbox(3, counters)  # type: ignore[arg-type]
    for i in range(5):
        inbox.put(("data", i))
    assert inbox.take(timeout=0.0) == [("data", 2), ("data", 3), ("data", 4)]
    assert counters["overflow"] == 2 and inbox.take(timeout=0.0) == []


def test_the_inbox_wakes_its_reader_on_a_put():
    inbox = Inbox(8, {"overflow": 0})  # type: ignore[arg-type]
    threading.Timer(0.05, inbox.put, args=(("data", 1),)).start()
    assert inbox.take(timeout=5.0) == [("data", 1)]


def test_the_inbox_keeps_its_bound_under_concurrent_puts():
    counters: dict[str, int] = {"overflow": 0}
    inbox = Inbox(50, counters)  # type: ignore[arg-type]
    threads = [
        threading.Thread(target=lambda n=n: [inbox.put((n, i)) for i in range(1000)])
        for n in range(4)
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    items = inbox.take(timeout=0.0)
    # Producers racing past a full inbox's check may each add one more.
    assert len(items) <= 50 + len(threads) and len(items) + counters["overflow"] == 4000
    for n in range(4):  # each producer's items stay in order
        mine = [i for m, i in items if m == n]
        assert mine == sorted(mine)


def worker_with_static(session: FakeSession, t: int) -> Worker:
    worker = Worker(SPEC, session, KEYS)
    session.deliver(KEYS.data("ART/WT"), pose(t, 0.5))
    return worker


class ThreadRecordingSession(FakeSession):
    """Records the name of the thread each put comes from."""

    def __init__(self) -> None:
        super().__init__()
        self.put_threads: set[str] = set()

    def declare_publisher(self, key, encoding=None, congestion_control=None):
        publisher = super().declare_publisher(key, encoding)

        def put(data: bytes, attachment: bytes | None = None) -> None:
            self.put_threads.add(threading.current_thread().name)
            publisher.put(data)

        return SimpleNamespace(
            put=put,
            undeclare=publisher.undeclare,
            matching_status=publisher.matching_status,
            declare_matching_listener=publisher.declare_matching_listener,
        )


def test_an_input_is_handled_on_its_own_thread_in_order():
    """Zenoh's thread only queues a sample in the input's channel; the input's own thread
    takes the samples waiting and handles them itself (one thread hand-off), in order."""
    session = ThreadRecordingSession()
    worker = worker_with_static(session, 1_000)
    session.deliver_burst(KEYS.data("ART/HT"), [pose(t) for t in (2_000, 3_000, 4_000)])
    assert [p.timestamp_ns for p in outputs(session)] == [2_000, 3_000, 4_000]
    assert session.put_threads == {f"input {KEYS.data('ART/HT')}"}
    assert worker.status()["handling_us"] > 0
    worker.stop()


def test_a_trigger_held_for_a_lagging_input_is_computed_when_its_wait_is_over():
    """A trigger that waits for another input (``ubitrack_agent.services.triggers``) is computed
    when its wait is over though no sample follows it: the input's thread that held it wakes the
    worker thread, which was waiting for commands far longer."""
    inputs = (
        InputBinding("AB", KEYS.data("ART/WT")),
        InputBinding("BC", KEYS.data("ART/HT"), trigger=True),
    )
    session = FakeSession()
    worker = Worker(dataclasses.replace(SPEC, inputs=inputs, wait_ms=50.0), session, KEYS)

    def worker_thread() -> None:
        while not worker.released:
            worker.step(longest_s=30.0)

    thread = threading.Thread(target=worker_thread)
    thread.start()
    try:
        t0 = time.time_ns() - 10**9
        for i in range(3):  # one every 10 ms: the trigger below waits 15 ms for the next
            session.deliver(KEYS.data("ART/WT"), pose(t0 + i * 10_000_000, 0.5))
        session.deliver(KEYS.data("ART/HT"), pose(t0 + 25_000_000))
        assert worker.counters["published"] + worker.counters["dropped"] == 0  # held
        deadline = time.monotonic() + 5.0
        while worker.counters["published"] + worker.counters["dropped"] == 0:
            assert time.monotonic() < deadline, "the held trigger was not computed"
            time.sleep(0.005)
    finally:
        session.deliver(KEYS.control("concat1"), b'{"stop": true}')
        thread.join(timeout=5.0)
    assert not thread.is_alive()


def test_a_worker_output_is_decoded_at_the_worker_level_by_its_consumer():
    """The consumer of a worker's output validates it at level WORKER, which does not check
    unit norm again (the producer's maths keeps it): a sample off by more than the strict
    tolerance, which a provider's input refuses, flows."""
    session = FakeSession()
    spec = SPEC.__class__(
        instance="concat2",
        service="concatenation",
        inputs=(
            InputBinding("AB", KEYS.data("ART/WT"), static=True),
            InputBinding("BC", KEYS.data("c1/AC"), trigger=True, from_worker=True),
        ),
        outputs={"AC": KEYS.data("concat1/AC")},
    )
    worker = Worker(spec, session, KEYS)
    session.deliver(KEYS.data("ART/WT"), pose(1_000))
    message = msgpack.unpackb(encode(Pose(2_000, IDENTITY, [0.0, 1.0, 0.0])))
    message["rotation"] = (np.array(IDENTITY) * (1 + 1e-5)).tobytes()
    session.deliver(KEYS.data("c1/AC"), msgpack.packb(message))
    worker.step(longest_s=0.0)
    assert (worker.counters["rejected"], worker.counters["published"]) == (0, 1)
    worker.stop()


class EagerSession(FakeSession):
    """Delivers a sample on a key the moment it is subscribed, as zenoh may."""

    def __init__(self, waiting: dict[str, bytes]) -> None:
        super().__init__()
        self.waiting = waiting

    def declare_subscriber(self, key, callback, allowed_origin=None):
        subscriber = super().declare_subscriber(key, callback, allowed_origin)
        if key in self.waiting:
            self.deliver(key, self.waiting.pop(key), wait=False)  # its thread not started
        return subscriber


def test_a_sample_arriving_while_the_inputs_are_bound_waits_for_them():
    """A sample zenoh delivers as its key is subscribed is handled once the inputs are set
    (when samples were handled on zenoh's thread, one met an empty input list: IndexError)."""
    session = EagerSession(
        {KEYS.data("ART/WT"): pose(1_000, 0.5), KEYS.data("ART/HT"): pose(2_000)}
    )
    worker = Worker(SPEC, session, KEYS)
    deadline = time.monotonic() + 5.0
    while worker.counters["received"] < 2 and time.monotonic() < deadline:
        worker.step(longest_s=0.05)
    assert (worker.counters["received"], worker.counters["internal_errors"]) == (2, 0)
    session.deliver(KEYS.data("ART/HT"), pose(3_000))
    worker.step(longest_s=0.0)
    assert [p.timestamp_ns for p in outputs(session)][-1] == 3_000
    worker.stop()


def test_huge_entries_cannot_widen_the_worker_level_tolerance():
    """An indefinite covariance whose trace overflows is refused at level WORKER too (the
    tolerance's scale was the trace: infinite, so anything passed)."""
    covariance = np.diag([1.5e308] * 5 + [-1e300])  # far beyond round-off of 1.5e308
    with pytest.raises(MeasurementError, match="not positive semi-definite"):
        check_semidefinite("cov", covariance)
    check_semidefinite("cov", np.diag([1.5e308] * 6))  # huge but positive definite


# -- a backlog handled as one run (issue 12: 20,000 ErrorPoses/s) -----------------------------


def _error_pose(t: int, seed: int, covariance: np.ndarray | None = None) -> ErrorPose:
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(6, 6)) * 1e-3
    q = Rotation.random(random_state=seed).as_quat()
    cov = a @ a.T + np.eye(6) * 1e-8 if covariance is None else covariance
    return ErrorPose(t, q, rng.normal(size=3), cov)


def _with_static_part(pose: ErrorPose) -> ErrorPose:
    """``pose`` with half its covariance marked static."""
    cov = pose.covariance
    return ErrorPose(pose.timestamp_ns, pose.rotation, pose.translation, cov, 0.5 * cov)


@settings(max_examples=80, deadline=None)
@given(
    st.integers(2, 40),
    st.integers(0, 2**32 - 1),
    st.sampled_from(["exact", "error", "static part"]),
    st.sampled_from(["exact", "error", "static part", "some with a static part"]),
)
def test_pose_pairs_compose_as_each_pair_alone(count, seed, first_kind, second_kind):
    """``compose_pose_pairs`` (a run's compositions in a few numpy calls) gives what
    ``compose_poses`` gives each pair, to round-off, in read-only arrays of the same types,
    static parts included."""
    rng = np.random.default_rng(seed)
    static = _error_pose(5, seed)
    if first_kind == "exact":
        static = Pose(5, static.rotation, static.translation)
    elif first_kind == "static part":
        static = _with_static_part(static)
    firsts = [static.restamped(10 + i) for i in range(count)]
    seconds = [_error_pose(10 + i, int(rng.integers(2**31))) for i in range(count)]
    if second_kind == "exact":
        seconds = [Pose(s.timestamp_ns, s.rotation, s.translation) for s in seconds]
    elif second_kind != "error":
        marked = range(count) if second_kind == "static part" else range(0, count, 2)
        seconds = [_with_static_part(s) if i in marked else s for i, s in enumerate(seconds)]
    for run, alone in zip(
        compose_pose_pairs(firsts, seconds),
        [compose_poses(a, b) for a, b in zip(firsts, seconds, strict=True)],
        strict=True,
    ):
        assert type(run) is type(alone) and run.timestamp_ns == alone.timestamp_ns
        for spec in alone.ARRAY_FIELDS:
            mine, theirs = getattr(run, spec.name), getattr(alone, spec.name)
            if theirs is None:
                assert mine is None
                continue
            assert mine.shape == theirs.shape and not mine.flags.writeable
            np.testing.assert_allclose(mine, theirs, rtol=1e-12, atol=1e-15)


def test_pose_pairs_of_different_first_poses_are_composed_one_by_one():
    firsts = [_error_pose(5, 1), _error_pose(5, 2)]
    seconds = [_error_pose(10, 3), _error_pose(11, 4)]
    alone = [compose_poses(a, b) for a, b in zip(firsts, seconds, strict=True)]
    assert compose_pose_pairs(firsts, seconds) == alone


def _backlog() -> list[bytes]:
    """ErrorPoses from a provider, one of them garbage, one not finite, one repeating an
    instant (a stale trigger), one with an indefinite covariance."""
    payloads = [encode(_error_pose(2_000 + 1_000 * i, i)) for i in range(24)]
    payloads[5] = b"\x93garbage"
    message = msgpack.unpackb(payloads[11])
    message["translation"] = np.array([0.0, np.nan, 0.0]).tobytes()
    payloads[11] = msgpack.packb(message)
    payloads[15] = payloads[14]
    message = msgpack.unpackb(payloads[19])
    message["covariance"] = (np.eye(6) - 2 * np.eye(6)[0]).tobytes()
    payloads[19] = msgpack.packb(message)
    return payloads


def test_a_backlog_is_handled_as_one_run_as_it_would_be_sample_by_sample():
    """Samples of the one dynamic input taken together are handled as one run
    (``Worker._on_run``: decoded together, composed together): the same outputs to
    round-off and the same counts as handling them one at a time."""
    payloads = _backlog()
    runs = []
    for together in (False, True):
        session = FakeSession()
        worker = Worker(SPEC, session, KEYS)
        session.deliver(KEYS.data("ART/WT"), encode(_error_pose(1_000, 99)))
        if together:
            session.deliver_burst(KEYS.data("ART/HT"), payloads)
        else:
            for payload in payloads:
                session.deliver(KEYS.data("ART/HT"), payload)
        worker.stop()
        runs.append((worker.counters, outputs(session)))
    (one_by_one, alone), (in_a_run, run) = runs
    assert (one_by_one["in_runs"], in_a_run["in_runs"]) == (0, len(payloads))
    assert {k: v for k, v in in_a_run.items() if k != "in_runs"} == {
        k: v for k, v in one_by_one.items() if k != "in_runs"
    }
    assert in_a_run["rejected"] == 3 and in_a_run["stale_triggers"] == 1
    assert len(run) == len(alone) == len(payloads) - 4
    for mine, theirs in zip(run, alone, strict=True):
        assert type(mine) is type(theirs) and mine.timestamp_ns == theirs.timestamp_ns
        np.testing.assert_allclose(mine.covariance, theirs.covariance, rtol=1e-12, atol=1e-18)
        np.testing.assert_allclose(mine.translation, theirs.translation, rtol=1e-12)


def test_a_short_backlog_or_one_of_two_dynamic_inputs_is_handled_sample_by_sample():
    """Fewer than ``RUN_MIN`` samples, or an input that is not the only dynamic one (its
    trigger may wait for the other), take the path of single samples."""
    session = FakeSession()
    worker = Worker(SPEC, session, KEYS)
    session.deliver(KEYS.data("ART/WT"), encode(_error_pose(1_000, 99)))
    short = [encode(_error_pose(2_000 + i, i)) for i in range(RUN_MIN - 1)]
    session.deliver_burst(KEYS.data("ART/HT"), short)
    assert (worker.counters["in_runs"], worker.counters["published"]) == (0, RUN_MIN - 1)
    worker.stop()
    both_dynamic = (
        InputBinding("AB", KEYS.data("ART/WT"), trigger=True),
        InputBinding("BC", KEYS.data("ART/HT")),
    )
    session = FakeSession()
    worker = Worker(dataclasses.replace(SPEC, inputs=both_dynamic), session, KEYS)
    session.deliver(KEYS.data("ART/HT"), encode(_error_pose(1_000, 99)))
    triggers = [encode(_error_pose(1_000 + 10 * i, i)) for i in range(2 * RUN_MIN)]
    session.deliver_burst(KEYS.data("ART/WT"), triggers)
    assert worker.counters["in_runs"] == 0 and worker.counters["received"] == 2 * RUN_MIN + 1
    worker.stop()


FATES = (
    "rejected",
    "rejected_future",
    "rejected_clock",
    "dropped_stale",
    "superseded",
    "buffered",
    "stale_triggers",
    "dropped",
    "published",
)
"""Where each sample a concatenation worker receives ends
(``ubitrack_agent.services.worker.COUNTERS``)."""


def test_rewires_while_an_input_thread_handles_bursts_lose_no_count_and_raise_nothing():
    """Races of the worker's lock: rewires (the same keys bound anew, each a new subscription)
    applied by the worker thread while the input's thread handles bursts of samples. Every
    sample received ends in exactly one counter, nothing raises, and the worker publishes
    again after the last rewire."""
    session = FakeSession()
    worker = worker_with_static(session, 1_000)
    stop = threading.Event()
    sent = [0]

    def flood() -> None:
        t = 2_000
        while not stop.is_set():
            channel = session.channels.get(KEYS.data("ART/HT"))
            if channel is not None:  # between an undeclare and the new subscription: none
                burst = [pose(t + i) for i in range(1 + sent[0] % 20)]
                channel.push_burst([zenoh_sample(p) for p in burst], wait=False)
                sent[0] += len(burst)
                t += len(burst)
            time.sleep(0.0005)

    flooding = threading.Thread(target=flood)
    flooding.start()
    try:
        for i in range(30):  # the dynamic input's binding changes, its key stays
            inputs = (SPEC.inputs[0], dataclasses.replace(SPEC.inputs[1], from_worker=i % 2 == 0))
            rewire = json.dumps({"inputs": [b.as_dict() for b in inputs]}).encode()
            session.deliver(KEYS.control("concat1"), rewire)
            worker.step(longest_s=0.0)
            time.sleep(0.002)
    finally:
        stop.set()
        flooding.join(timeout=5.0)
    published = worker.counters["published"]
    session.deliver(KEYS.data("ART/HT"), pose(10**9))
    counters = worker.counters
    assert counters["rewired"] == 30 and counters["internal_errors"] == 0
    assert counters["published"] > published  # the last subscription is handled
    assert counters["superseded"] + counters["in_runs"] > 0  # the race was run
    assert counters["received"] == sum(counters[fate] for fate in FATES)
    worker.stop()
