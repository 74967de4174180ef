"""Inversions folded into the one component reading their output (``agent.materialise.fold``,
``fold_inversions``; ``net.spec`` ``inverted`` and ``before_port``; the worker's inverted
inputs): the same values, computed in the reader's process, a hop fewer."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import pytest

from services.registry import lookup
from services.spec import check_bindings
from services.worker import Worker, _histories
from tests.unit.test_fold import PRODUCER, figure6_specs, sample
from tests.unit.test_worker_inputs import IDENTITY, KEYS, FakeSession
from ubitrack_agent.agent.materialise import fold, fold_inversions, fold_static_compositions
from ubitrack_agent.core import Pose, Rotation3D, decode, encode
from ubitrack_agent.core.poses import compose_poses, invert_pose
from ubitrack_agent.net.spec import (
    ComponentSpec,
    InputBinding,
    SpecError,
    before_port,
    parse_before_port,
    parse_bindings,
    then_port,
)


def test_the_figure6_flow_reads_the_art_tracker_in_the_fusion():
    """The A.R.T. path (an inversion composed with two calibrations) runs in the fusion: a
    fused pose passes two workers (pose estimation, fusion) from the camera and one from the
    A.R.T. tracker, as C->A from the A.R.T. path alone does."""
    specs = figure6_specs()
    folded, into = fold(specs)
    assert sorted(spec.service for spec in folded.values()) == ["fusion", "pose_estimation_2d3d"]
    fusion = next(s for s in folded.values() if s.service == "fusion")
    (index, art), *others = [
        (i, b) for i, b in enumerate(fusion.inputs) if b.inverted or b.key == "ART->HT:6D"
    ]
    assert not others and art.key == "ART->HT:6D" and art.inverted and art.trigger
    assert not art.from_worker  # a provider's samples: validated in full
    composed = [(parse_before_port(b.port), b.key) for b in fusion.inputs]
    composed = [(port, key) for port, key in composed if port is not None]
    assert composed == [((index, 0, "BC"), "ART->WT:6D"), ((index, 1, "AB"), "C->HT:6D")]
    # Every component of the A.R.T. chain, and the last concatenation, runs in the fusion.
    assert set(into) == set(specs) - {s.instance for s in folded.values()}
    assert set(into.values()) == {fusion.instance}
    for spec in folded.values():  # every specification still fits its service
        check_bindings(spec.inputs, lookup(spec.service), spec.expansion)


def _reader(binding: InputBinding) -> ComponentSpec:
    return ComponentSpec("r", "relay", (binding,), {"out": "r/out"})


FROM_INV = InputBinding("in", "inv/BA", trigger=True, from_worker=True)


def test_an_inversion_is_folded_only_into_its_one_dynamic_reader():
    folded, into = fold_inversions({"inv": PRODUCER, "r": _reader(FROM_INV)})
    assert into == {"inv": "r"}
    assert folded["r"].inputs == (InputBinding("in", "ART->HT", trigger=True, inverted=True),)
    two = {"inv": PRODUCER, "r": _reader(FROM_INV), "s": replace(_reader(FROM_INV), instance="s")}
    routed = replace(PRODUCER, relations={"BA": ("relation",)})
    static_source = replace(PRODUCER, inputs=(InputBinding("AB", "ART->WT", True, True),))
    for kept in (
        two,  # read twice
        {"inv": routed, "r": _reader(FROM_INV)},  # a relation is published on its output
        {"inv": static_source, "r": _reader(FROM_INV)},  # no hop per sample to save
        {"inv": PRODUCER, "r": _reader(replace(FROM_INV, static=True, trigger=False))},
        {"inv": PRODUCER, "r": _reader(replace(FROM_INV, inverted=True))},
    ):
        assert fold_inversions(kept) == (kept, {})
    kept = {"inv": PRODUCER, "r": _reader(FROM_INV)}
    assert fold_inversions(kept, keep={"inv"}) == (kept, {})  # host labels
    assert fold_inversions(kept, keep={"r"}) == (kept, {})


def test_a_static_composition_folded_into_a_folded_inversion_runs_in_its_reader():
    static = InputBinding("AB", "C->HT", static=True)
    concatenation = ComponentSpec(
        "k", "concatenation", (static, replace(FROM_INV, port="BC")), {"AC": "k/AC"}
    )
    reader = _reader(replace(FROM_INV, key="k/AC"))
    specs, into = fold({"inv": PRODUCER, "k": concatenation, "r": reader})
    assert into == {"k": "r", "inv": "r"} and set(specs) == {"r"}
    assert specs["r"].inputs == (
        InputBinding("in", "ART->HT", trigger=True, inverted=True),
        InputBinding(before_port(0, 0, "AB"), "C->HT", static=True),
    )
    assert fold_static_compositions({"inv": PRODUCER, "k": concatenation, "r": reader})[1] == {
        "k": "inv"
    }


def test_an_inverted_input_goes_over_the_wire_and_back():
    binding = InputBinding("AB", KEYS.data("ART/HT"), trigger=True, inverted=True)
    assert parse_bindings([binding.as_dict()]) == (binding,)
    assert "inverted" not in replace(binding, inverted=False).as_dict()
    with pytest.raises(SpecError, match="inverted must be true or false"):
        parse_bindings([{**binding.as_dict(), "inverted": 1}])


@pytest.mark.parametrize(
    "bindings, fault",
    [
        ((InputBinding(before_port(0, 0, "AB"), "k", static=True),), "no inverted input"),
        ((InputBinding(before_port(5, 0, "AB"), "k", static=True),), "no inverted input"),
        ((InputBinding(before_port(1, 0, "AB"), "k", static=True),), "no inverted input"),
        ((InputBinding(before_port(0, 1, "AB"), "k", static=True),), "numbered 0..n"),
        ((InputBinding(before_port(0, 0, "AB"), "k"),), "static and no trigger"),
        ((InputBinding(before_port(0, 0, "AB"), "k", static=True, inverted=True),), "static"),
    ],
)
def test_an_edge_composed_with_an_inverted_input_is_checked(bindings, fault):
    inverted = InputBinding("AB", "ART->HT", trigger=True, inverted="no inverted" not in fault)
    with pytest.raises(SpecError, match=fault):
        check_bindings((inverted, *bindings), lookup("inversion"), "none")


def test_an_inverted_input_is_dynamic_and_takes_what_an_inversion_gives():
    static = InputBinding("AB", "ART->HT", trigger=True, static=True, inverted=True)
    with pytest.raises(SpecError, match="an inverted input is dynamic"):
        check_bindings((static,), lookup("inversion"), "none")
    triangulation = lookup("triangulation")
    port = next(iter(triangulation.INPUTS))  # image positions: nothing an inversion gives
    bindings = tuple(
        InputBinding(p, f"k{p}", trigger=True, inverted=p == port) for p in triangulation.INPUTS
    )
    with pytest.raises(SpecError, match="takes nothing an inversion gives"):
        check_bindings(bindings, triangulation, "none")


# -- the worker's inverted inputs -------------------------------------------------------------


def fusion_reading_the_art_tracker(session: FakeSession) -> Worker:
    """The figure-6 fusion with the A.R.T. path folded into it (``fold``)."""
    spec = ComponentSpec(
        "fusion",
        "fusion",
        (
            InputBinding("AB", KEYS.data("pe/CWT"), trigger=True, from_worker=True),
            InputBinding("AB", KEYS.data("ART/HT"), trigger=True, inverted=True),
            InputBinding(then_port("fused", 0, "BC"), KEYS.data("db/WT_A"), static=True),
            InputBinding(before_port(1, 0, "BC"), KEYS.data("db/ART_WT"), static=True),
            InputBinding(before_port(1, 1, "AB"), KEYS.data("db/C_HT"), static=True),
        ),
        {"fused": KEYS.data("fusion/fused")},
        expansion="space",
    )
    return Worker(spec, session, KEYS)


def test_an_inverted_input_gives_what_the_inversion_and_its_concatenations_published():
    session = FakeSession()
    worker = fusion_reading_the_art_tracker(session)
    t = time.time_ns()
    wt_a = Pose(1, IDENTITY, [0.0, 0.0, 1.0])
    art_wt, c_ht, art_ht = sample(1, 0.4, 1e-8), sample(1, -0.7, 2e-8), sample(t, 1.1)
    for key, value in (("db/WT_A", wt_a), ("db/ART_WT", art_wt), ("db/C_HT", c_ht)):
        session.deliver(KEYS.data(key), encode(value))
    session.deliver(KEYS.data("ART/HT"), encode(art_ht))
    worker.step(longest_s=0.0)
    published = [decode(data) for key, data in session.puts if key == KEYS.data("fusion/fused")]
    # What the inversion worker (composing with ART->WT, then C->HT) published.
    estimate = compose_poses(
        c_ht.restamped(t), compose_poses(invert_pose(art_ht), art_wt.restamped(t))
    )
    # A filter's first output is its first measurement, here composed with WT->A.
    expected = compose_poses(estimate, wt_a.restamped(t))
    assert len(published) == 1
    np.testing.assert_allclose(published[0].translation, expected.translation, atol=1e-12)
    np.testing.assert_allclose(published[0].rotation, expected.rotation, atol=1e-12)
    np.testing.assert_allclose(published[0].covariance, expected.covariance, atol=1e-18)
    worker.stop()


def test_an_inverted_input_waits_for_its_static_edges_and_says_so():
    session = FakeSession()
    worker = fusion_reading_the_art_tracker(session)
    session.deliver(KEYS.data("db/WT_A"), encode(Pose(1, IDENTITY, [0.0, 0.0, 1.0])))
    session.deliver(KEYS.data("ART/HT"), encode(sample(time.time_ns(), 1.0)))
    worker.step(longest_s=0.0)
    assert not session.puts and worker.counters["dropped"] == 1
    worker.stop()


def test_an_inverted_input_the_maths_cannot_compose_is_counted_and_the_worker_goes_on():
    """A static edge of a type the concatenation refuses after a pose (a 3D rotation as the
    second factor): each sample is counted ``failed``, nothing is published, and the worker
    takes the next one."""
    session = FakeSession()
    worker = fusion_reading_the_art_tracker(session)
    session.deliver(KEYS.data("db/WT_A"), encode(Pose(1, IDENTITY, [0.0, 0.0, 1.0])))
    session.deliver(KEYS.data("db/ART_WT"), encode(Rotation3D(1, IDENTITY)))
    session.deliver(KEYS.data("db/C_HT"), encode(sample(1, -0.7)))
    t = time.time_ns()
    for k in range(3):
        session.deliver(KEYS.data("ART/HT"), encode(sample(t + k, 1.0)))
    worker.step(longest_s=0.0)
    assert worker.counters["failed"] == 3 and not session.puts
    assert worker.counters["internal_errors"] == 0
    worker.stop()


def test_a_rewire_keeps_an_inputs_history_only_while_its_samples_stay_the_same():
    inverted = InputBinding("AB", "ART->HT", trigger=True, inverted=True)
    edge = InputBinding(before_port(0, 0, "BC"), "ART->WT", static=True)
    plain, other_edge = replace(inverted, inverted=False), replace(edge, key="X->WT")
    assert _histories((inverted, edge))[0] == _histories([inverted, edge])[0]
    assert _histories((inverted, edge))[0] != _histories((plain,))[0]
    assert _histories((inverted, edge))[0] != _histories((inverted, other_edge))[0]
    assert _histories((inverted, edge))[0] != _histories((inverted,))[0]
