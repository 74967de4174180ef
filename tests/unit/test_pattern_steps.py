"""Each step of a pattern is a component of its own (issue 28: the fold's special cases
retired into containers). The figure-6 flow's specifications name only their services' own
ports; a derivation on one host runs in one container, its components wired in the process;
a template may ask for a container of its own; and the A.R.T. chain running as three
components of a container gives the values of the maths called directly."""

from __future__ import annotations

import threading
import time
from dataclasses import replace

import numpy as np
import pytest

from tests.unit.test_container import MatchingSession, wait_for
from tests.unit.test_worker_inputs import KEYS
from ubitrack_agent.agent.materialise import component_specs
from ubitrack_agent.agent.placement import group_containers
from ubitrack_agent.agent.planning import template_needs
from ubitrack_agent.commands.plan_inputs import load_plan_srg
from ubitrack_agent.core import ErrorPose, Pose, encode
from ubitrack_agent.core.poses import compose_poses, invert_pose, with_static_error
from ubitrack_agent.graph.dataflow import DataFlow, from_solution, relation_name
from ubitrack_agent.graph.planner import Query, plan
from ubitrack_agent.graph.templates import load_templates
from ubitrack_agent.net.keys import RelationId
from ubitrack_agent.net.spec import ComponentSpec, InputBinding, SpecError, parse_bindings
from ubitrack_agent.services.container import Container
from ubitrack_agent.services.registry import lookup
from ubitrack_agent.services.spec import check_bindings, check_spec

C_A = Query("C", "A", "6D", False)
C_A_KEY = KEYS.relation(RelationId("C", "A", "6D"))


class EdgeKeys:
    """The test domain's keys for the example's edge ids (``C->IP:3x4`` is no key name)."""

    def data(self, edge_id: str) -> str:
        return KEYS.data(edge_id.replace("->", "_"))

    def relation(self, relation: RelationId) -> str:
        return KEYS.relation(relation)


def figure6() -> tuple[DataFlow, dict[str, ComponentSpec]]:
    """The paper's figure 6 flow (``examples/paper_tracking.yaml``) and its specifications."""
    srg, _ = load_plan_srg(["examples/paper_tracking.yaml"])
    flow = from_solution(plan(srg, load_templates(None), C_A)[0], C_A)
    relation = {relation_name(C_A): RelationId("C", "A", "6D")}
    return flow, component_specs(flow, srg, EdgeKeys(), relation)


def of_service(specs: dict[str, ComponentSpec], service: str) -> list[ComponentSpec]:
    return [spec for spec in specs.values() if spec.service == service]


def test_the_figure6_flow_is_one_component_per_step_each_wired_as_its_service_declares():
    flow, specs = figure6()
    assert list(specs) == list(flow.components)  # no relay: C->A comes from a step
    assert sorted(spec.service for spec in specs.values()) == [
        "concatenation",
        "concatenation",
        "concatenation",
        "fusion",
        "inversion",
        "pose_estimation_2d3d",
    ]
    for spec in specs.values():  # every binding on a port of its service: none encoded
        check_spec(spec)
        assert set(b.port for b in spec.inputs) <= set(lookup(spec.service).INPUTS)
    # The relation leaves from the last step, the concatenation after the fusion.
    (last,) = [spec for spec in specs.values() if spec.relations]
    (fusion,) = of_service(specs, "fusion")
    assert last.relations == {"AC": (C_A_KEY,)}
    assert fusion.outputs["fused"] in {b.key for b in last.inputs}


def test_a_derivation_on_one_host_runs_in_one_container_wired_in_the_process():
    _, specs = figure6()
    groups = group_containers(specs, dict.fromkeys(specs, "room"), {"room": 2})
    (group,) = groups.values()
    assert [spec.instance for spec in group.components] == list(specs)
    wired = {(wire.reader, wire.index) for wire in group.wires}
    from_components = {
        (spec.instance, index)
        for spec in specs.values()
        for index, binding in enumerate(spec.inputs)
        if binding.from_worker
    }
    assert wired == from_components and len(wired) == 5  # every hop inside the process


def test_a_template_asking_for_isolation_gives_its_components_a_container_of_their_own():
    flow, specs = figure6()
    templates = [
        replace(t, isolation="own") if t.name == "pose_estimation_2d3d" else t
        for t in load_templates(None)
    ]
    labels, isolated = template_needs(flow, templates)
    (estimation,) = of_service(specs, "pose_estimation_2d3d")
    assert isolated == {estimation.instance}
    assert set(labels) == set(flow.components) and not any(labels.values())
    groups = group_containers(specs, dict.fromkeys(specs, "hmd"), {"hmd": 1}, isolated)
    alone = f"hmd-{estimation.instance}"
    assert sorted(groups) == ["hmd-0", alone]
    assert groups[alone].components == (estimation,)
    assert len(groups["hmd-0"].components) == 5  # the rest together, the estimate over zenoh
    assert template_needs(flow, load_templates(None))[1] == frozenset()  # shared by default


def test_a_binding_on_no_port_of_its_service_or_with_an_unknown_field_is_refused():
    trigger = InputBinding("AB", KEYS.data("ART/HT"), trigger=True)
    composed = InputBinding("then/BA/0/BC", KEYS.data("db/ART_WT"), static=True)
    with pytest.raises(SpecError, match="has no input 'then/BA/0/BC'"):
        check_bindings((trigger, composed), lookup("inversion"), "none")
    inverted = {"port": "AB", "key": KEYS.data("ART/HT"), "trigger": True, "inverted": True}
    with pytest.raises(SpecError, match=r"unknown fields \['inverted'\]"):
        parse_bindings([inverted])


def pose(t: int, x: float, covariance: float = 1e-6) -> ErrorPose:
    angle = 0.3 * x
    rotation = [0.0, np.sin(angle / 2), 0.0, np.cos(angle / 2)]
    return ErrorPose(t, rotation, [x, 0.2, -0.1], np.eye(6) * covariance)


def test_the_art_chain_in_a_container_gives_the_values_of_the_maths_called_directly():
    """Inversion, then concatenations with ``ART->WT`` and ``C->HT`` (the paper's figure 6):
    three components handing over objects, the last one's output read outside the process,
    with the static edges' share of its covariance."""
    _, specs = figure6()
    (inversion,) = of_service(specs, "inversion")
    chain = [inversion]
    while len(chain) < 3:
        (reader,) = [
            s for s in specs.values() if set(chain[-1].outputs.values()) & {b.key for b in s.inputs}
        ]
        chain.append(reader)
    assert [spec.service for spec in chain] == ["inversion", "concatenation", "concatenation"]
    session = MatchingSession()
    last = chain[-1].outputs["AC"]
    session.quiet = {key for spec in chain[:-1] for key in spec.outputs.values()}  # read inside
    container = Container(session, KEYS, "c0", components=chain)
    session.scheduler = container.scheduler  # static samples handled there: waited for
    thread = threading.Thread(target=container.run, daemon=True)
    thread.start()
    try:
        art_wt, c_ht = pose(1, 0.4, 1e-8), pose(1, -0.7, 2e-8)
        session.deliver(EdgeKeys().data("ART->WT:6D"), encode(art_wt))
        session.deliver(EdgeKeys().data("C->HT:6D"), encode(c_ht))
        t = time.time_ns()
        art_ht = pose(t, 1.1)
        session.deliver(EdgeKeys().data("ART->HT:6D"), encode(art_ht))
        published = wait_for(lambda: [v for k, v in session.puts if k == last])
        handed_over = [e.worker.counters["handed_over"] for e in container.components.values()]
    finally:
        container.stop()
        thread.join(timeout=5)
    static_art_wt, static_c_ht = with_static_error(art_wt), with_static_error(c_ht)
    expected = compose_poses(
        static_c_ht.restamped(t), compose_poses(invert_pose(art_ht), static_art_wt.restamped(t))
    )
    assert published == [encode(expected)]  # the same bytes as one process computing it
    # The static edges' share of the covariance, carried through: that of the same chain with
    # the tracker's pose exact.
    exact_art_ht = Pose(t, art_ht.rotation, art_ht.translation)
    static_part = compose_poses(c_ht, compose_poses(invert_pose(exact_art_ht), art_wt))
    np.testing.assert_allclose(expected.static_covariance, static_part.covariance, rtol=1e-12)
    assert handed_over == [1, 1, 0]  # the inversion's and the first concatenation's outputs
