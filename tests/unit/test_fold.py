"""Concatenations with a static edge folded into the worker producing their other input
(``agent.materialise.fold_static_compositions``, ``net.spec.then_port``, the worker's
composition): the same values on the same keys, a hop fewer. The ports of composed edges, and
a worker taking any of them, also those of an inverted input (``test_fold_inversions.py``)."""

from __future__ import annotations

import json
import time
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from services.registry import lookup
from services.spec import check_bindings
from services.worker import Worker
from tests.unit.test_worker_inputs import IDENTITY, KEYS, FakeSession
from ubitrack_agent.agent.materialise import component_specs, fold_static_compositions
from ubitrack_agent.agent.reconcile import reconcile
from ubitrack_agent.commands.plan import _EdgeIds
from ubitrack_agent.commands.plan_inputs import load_plan_srg
from ubitrack_agent.core import ErrorPose, Pose, decode, encode
from ubitrack_agent.core.poses import compose_poses, invert_pose
from ubitrack_agent.graph.dataflow import from_solution, relation_name
from ubitrack_agent.graph.planner import Query, plan
from ubitrack_agent.graph.templates import load_templates
from ubitrack_agent.net.keys import RelationId
from ubitrack_agent.net.spec import (
    ComponentSpec,
    InputBinding,
    SpecError,
    before_port,
    parse_before_port,
    parse_then_port,
    then_port,
)

C_A = Query("C", "A", "6D", False)
SIDES = st.sampled_from(["AB", "BC"])


def figure6_specs() -> dict[str, ComponentSpec]:
    """The worker specifications of the paper's figure 6 flow (``examples/``)."""
    srg, _ = load_plan_srg(["examples/paper_tracking.yaml"])
    flow = from_solution(plan(srg, load_templates(None), C_A)[0], C_A)
    relation = {relation_name(C_A): RelationId("C", "A", "6D")}
    return component_specs(flow, srg, _EdgeIds(), relation)


def test_the_figure6_flow_loses_its_concatenations_with_static_edges():
    specs = figure6_specs()
    folded, into = fold_static_compositions(specs)
    services = sorted(spec.service for spec in folded.values())
    assert services == ["fusion", "inversion", "pose_estimation_2d3d"]
    inversion = next(s for s in folded.values() if s.service == "inversion")
    fusion = next(s for s in folded.values() if s.service == "fusion")
    # The A.R.T. chain: HT->ART, then ART->WT after it, then C->HT before it.
    composed = [b for b in inversion.inputs if parse_then_port(b.port)]
    assert [(parse_then_port(b.port), b.key) for b in composed] == [
        (("BA", 0, "BC"), "ART->WT:6D"),
        (("BA", 1, "AB"), "C->HT:6D"),
    ]
    assert all(b.static and not b.trigger for b in composed)
    # The last hop: the fusion publishes C->A where the concatenation did, for the relation.
    last = next(i for i, s in specs.items() if s.relations)
    assert into[last] == fusion.instance
    assert fusion.outputs == {"fused": specs[last].outputs["AC"]}
    assert fusion.relations == {"fused": specs[last].relations["AC"]}
    assert set(into.values()) == {inversion.instance, fusion.instance}
    for spec in folded.values():  # every specification still fits its service
        check_bindings(spec.inputs, lookup(spec.service), spec.expansion)


def _concatenation(instance: str, ab: InputBinding, bc: InputBinding) -> ComponentSpec:
    return ComponentSpec(instance, "concatenation", (ab, bc), {"AC": f"{instance}/AC"})


PRODUCER = ComponentSpec(
    "inv", "inversion", (InputBinding("AB", "ART->HT", trigger=True),), {"BA": "inv/BA"}
)
STATIC = InputBinding("AB", "C->HT", static=True)
FROM_INV = InputBinding("BC", "inv/BA", trigger=True, from_worker=True)


def test_a_concatenation_is_folded_only_where_nothing_else_needs_its_input():
    folded, _ = fold_static_compositions(
        {"inv": PRODUCER, "k": _concatenation("k", STATIC, FROM_INV)}
    )
    assert set(folded) == {"inv"}
    other = ComponentSpec("other", "relay", (replace(FROM_INV, port="in"),), {"out": "other/out"})
    kept = {"inv": PRODUCER, "k": _concatenation("k", STATIC, FROM_INV), "other": other}
    assert set(fold_static_compositions(kept)[0]) == set(kept)  # inv/BA read twice
    routed = replace(PRODUCER, relations={"BA": ("relation",)})
    kept = {"inv": routed, "k": _concatenation("k", STATIC, FROM_INV)}
    assert set(fold_static_compositions(kept)[0]) == set(kept)  # inv/BA is a relation
    measured = InputBinding("BC", "ART->HT", trigger=True)  # a provider's, not a worker's
    kept = {"inv": PRODUCER, "k": _concatenation("k", STATIC, measured)}
    assert set(fold_static_compositions(kept)[0]) == set(kept)
    both_dynamic = replace(FROM_INV, port="AB"), InputBinding("BC", "X->Y", trigger=True)
    kept = {"inv": PRODUCER, "k": _concatenation("k", *both_dynamic)}
    assert set(fold_static_compositions(kept)[0]) == set(kept)
    kept = {"inv": PRODUCER, "k": _concatenation("k", STATIC, FROM_INV)}
    assert set(fold_static_compositions(kept, keep={"k"})[0]) == set(kept)  # host labels


@pytest.mark.parametrize(
    "binding, fault",
    [
        (InputBinding(then_port("nope", 0, "AB"), "k", static=True), "no output 'nope'"),
        (InputBinding(then_port("BA", 0, "AB"), "k"), "static and no trigger"),
        (InputBinding(then_port("BA", 0, "AB"), "k", True, True), "static and no trigger"),
        (InputBinding(then_port("BA", 1, "AB"), "k", static=True), "numbered 0..n"),
    ],
)
def test_a_composed_edge_is_checked_against_the_service(binding, fault):
    bindings = (InputBinding("AB", "ART->HT", trigger=True), binding)
    with pytest.raises(SpecError, match=fault):
        check_bindings(bindings, lookup("inversion"), "none")


@given(
    st.text(max_size=40)
    | st.builds(
        "{}/{}/{}/{}".format,
        st.sampled_from(["then", "before"]),
        st.sampled_from(["BA", "", "x/y", "0", "12", "01"]),
        st.sampled_from(["0", "1", "01", "1000", "-1", "\u0663", " 2"]),
        st.sampled_from(["AB", "BC", "CD"]),
    )
)
def test_any_port_name_is_a_composed_edge_or_not_without_error(port: str):
    then, before = parse_then_port(port), parse_before_port(port)
    assert then is None or then_port(*then) == port  # one spelling per edge
    assert before is None or before_port(*before) == port
    assert then is None or before is None


composed_edges = st.lists(
    st.builds(
        InputBinding,
        st.builds(then_port, st.sampled_from(["BA", "AB"]), st.integers(0, 3), SIDES)
        | st.builds(before_port, st.integers(0, 2), st.integers(0, 3), SIDES),
        st.sampled_from([KEYS.data("db/a"), KEYS.data("db/b")]),
        st.booleans(),
        st.booleans(),
        st.just(0),
        st.just(False),
        st.booleans(),
    ),
    max_size=4,
)


@given(st.booleans(), composed_edges)
def test_a_worker_takes_any_composed_edges_that_pass_the_check_and_only_those(inverted, edges):
    """Whatever composed edges (of an output, of an inverted input) a specification from the
    network holds, the check refuses it with a ``SpecError`` or a worker runs it."""
    bindings = (InputBinding("AB", KEYS.data("ART/HT"), trigger=True, inverted=inverted), *edges)
    try:
        check_bindings(bindings, lookup("inversion"), "none")
    except SpecError:
        return
    spec = ComponentSpec("inv", "inversion", bindings, {"BA": KEYS.data("inv/BA")})
    worker = Worker(spec, FakeSession(), KEYS)
    composed = sum(len(edges) for edges in worker._then.values()) + len(worker._inputs[0].edges)
    assert composed == len(edges)
    worker.stop()


# -- the worker's composition -----------------------------------------------------------------


def folded_inversion_worker(session: FakeSession) -> Worker:
    spec = ComponentSpec(
        "inv",
        "inversion",
        (
            InputBinding("AB", KEYS.data("ART/HT"), trigger=True),
            InputBinding(then_port("BA", 0, "BC"), KEYS.data("db/ART_WT"), static=True),
            InputBinding(then_port("BA", 1, "AB"), KEYS.data("db/C_HT"), static=True),
        ),
        {"BA": KEYS.data("k2/AC")},
    )
    return Worker(spec, session, KEYS)


def sample(t: int, x: float, covariance: float = 1e-6) -> ErrorPose:
    angle = 0.3 * x
    rotation = [0.0, np.sin(angle / 2), 0.0, np.cos(angle / 2)]
    return ErrorPose(t, rotation, [x, 0.2, -0.1], np.eye(6) * covariance)


def test_a_folded_output_is_what_the_concatenations_published():
    session = FakeSession()
    worker = folded_inversion_worker(session)
    t = time.time_ns()
    art_wt, c_ht, art_ht = sample(1, 0.4, 1e-8), sample(1, -0.7, 2e-8), sample(t, 1.1)
    for key, value in (("db/ART_WT", art_wt), ("db/C_HT", c_ht), ("ART/HT", art_ht)):
        session.deliver(KEYS.data(key), encode(value))
        worker.step(longest_s=0.0)
    published = [decode(data) for key, data in session.puts if key == KEYS.data("k2/AC")]
    expected = compose_poses(
        c_ht.restamped(t), compose_poses(invert_pose(art_ht), art_wt.restamped(t))
    )
    assert len(published) == 1 and published[0] == decode(encode(expected))
    worker.stop()


def test_a_folded_output_waits_for_its_static_edges_and_says_so():
    session = FakeSession()
    worker = folded_inversion_worker(session)
    session.deliver(KEYS.data("ART/HT"), encode(sample(time.time_ns(), 1.0)))
    worker.step(longest_s=0.0)
    assert not session.puts and worker.counters["dropped"] == 1
    worker.stop()


def test_an_asynchronous_service_never_takes_a_composed_edge_for_an_estimate():
    session = FakeSession()
    spec = ComponentSpec(
        "fusion",
        "fusion",
        (
            InputBinding("AB", KEYS.data("a/CWT"), trigger=True),
            InputBinding("AB", KEYS.data("b/CWT"), trigger=True),
            InputBinding(then_port("fused", 0, "BC"), KEYS.data("db/WT_A"), static=True),
        ),
        {"fused": KEYS.data("k3/AC")},
        expansion="space",
    )
    worker = Worker(spec, session, KEYS)
    t = time.time_ns()
    wt_a = Pose(1, IDENTITY, [0.0, 0.0, 1.0])
    session.deliver(KEYS.data("db/WT_A"), encode(wt_a))
    session.deliver(KEYS.data("a/CWT"), encode(sample(t, 0.5)))
    worker.step(longest_s=0.0)
    published = [decode(data) for key, data in session.puts if key == KEYS.data("k3/AC")]
    assert len(published) == 1 and worker.counters["buffered"] == 1
    # A filter's first output is its first measurement, here composed with WT->A.
    expected = compose_poses(sample(t, 0.5), wt_a.restamped(t))
    np.testing.assert_allclose(published[0].translation, expected.translation, atol=1e-12)
    np.testing.assert_allclose(published[0].rotation, expected.rotation, atol=1e-12)
    worker.stop()


# -- a fold that comes or goes rewires in place ---------------------------------------------------


def test_a_fold_coming_or_going_rewires_its_producer_in_place():
    """A worker's output keys change in place (a control command), so a producer a
    concatenation is folded into, or taken out of, keeps running: the transition costs a
    rewire, not a new process."""
    specs = figure6_specs()
    folded, into = fold_static_compositions(specs)
    for instance in set(into.values()):
        actions = reconcile({instance: specs[instance]}, {instance: folded[instance]})
        assert not actions.stop and not actions.start
        (_, command), *_ = actions.update
        assert set(command) <= {"inputs", "outputs", "relations"} and "outputs" in command


def test_a_worker_moves_its_output_to_another_key_on_command():
    session = FakeSession()
    worker = folded_inversion_worker(session)
    moved = KEYS.data("k9/AC")
    command = {"outputs": {"BA": moved}}
    session.deliver(KEYS.control("inv"), json.dumps(command).encode())
    worker.step(longest_s=0.0)
    assert worker.counters["rewired"] == 1 and worker.spec.outputs == {"BA": moved}
    for key, value in (("db/ART_WT", sample(1, 0.4)), ("db/C_HT", sample(1, -0.7))):
        session.deliver(KEYS.data(key), encode(value))
    session.deliver(KEYS.data("ART/HT"), encode(sample(time.time_ns(), 1.1)))
    worker.step(longest_s=0.0)
    assert [key for key, _ in session.puts] == [moved]
    worker.stop()


@pytest.mark.parametrize(
    "outputs", [{"nope": KEYS.data("k9/AC")}, {"BA": "ubitrack/test/data/*"}, {"BA": 3}, []]
)
def test_a_bad_output_command_is_refused_and_counted(outputs):
    session = FakeSession()
    worker = folded_inversion_worker(session)
    before = worker.spec
    session.deliver(KEYS.control("inv"), json.dumps({"outputs": outputs}).encode())
    worker.step(longest_s=0.0)
    assert worker.counters["rejected_commands"] == 1 and worker.spec == before
    worker.stop()
