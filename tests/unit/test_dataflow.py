"""Data flow graphs: construction from a solution, sharing between queries (section 5.1)."""

from __future__ import annotations

import json
from dataclasses import replace

from ubitrack_agent.graph.dataflow import (
    Binding,
    DataFlow,
    from_solution,
    merge,
    plan_flows,
    relation_name,
)
from ubitrack_agent.graph.planner import Query, plan
from ubitrack_agent.graph.srg import remove_provider

QUERY = Query("C", "A", "6D")


def flow_for(srg, templates, query=QUERY):
    return from_solution(plan(srg, templates, query)[0], query)


def by_pattern(flow):
    out = {}
    for component in flow.components.values():
        out.setdefault(component.pattern, []).append(component)
    return out


def test_figure_6_data_flow_components_and_bindings(tracking_setup, templates):
    flow = flow_for(tracking_setup, templates)
    parts = by_pattern(flow)
    assert {k: len(v) for k, v in parts.items()} == {
        "PoseEstimation2D3D": 1,
        "Inversion": 1,
        "Concatenation": 3,
        "MultiTrackerFusion": 1,
    }
    (pose,) = parts["PoseEstimation2D3D"]
    inputs = dict(pose.inputs)
    assert inputs["CI"] == Binding(None, "C->IP:3x4")
    assert {inputs[f"IF[{k}]"].edge for k in range(5)} == {f"IP->F{i}:2D" for i in range(1, 6)}
    assert all(b.component is None for b in inputs.values())  # measured edges only
    assert pose.service == "pose_estimation_2d3d"

    (inversion,) = parts["Inversion"]
    assert dict(inversion.inputs) == {"AB": Binding(None, "ART->HT:6D")}

    (fusion,) = parts["MultiTrackerFusion"]
    producers = {flow.components[b.component].pattern for _, b in fusion.inputs}
    assert producers == {"PoseEstimation2D3D", "Concatenation"}

    final = flow.relations[relation_name(QUERY)]
    last = flow.components[final.component]
    assert last.pattern == "Concatenation" and final.edge == "AC"
    assert dict(last.inputs)["AB"].component == fusion.id
    assert dict(last.inputs)["BC"] == Binding(None, "WT->A:6D")


def test_component_ids_are_stable_across_plans(tracking_setup, templates):
    assert set(flow_for(tracking_setup, templates).components) == set(
        flow_for(tracking_setup, templates).components
    )


def test_queries_share_components(tracking_setup, templates):
    to_a = flow_for(tracking_setup, templates)
    to_wt = flow_for(tracking_setup, templates, Query("C", "WT", "6D"))
    shared = set(to_a.components) & set(to_wt.components)
    assert len(shared) >= 4  # pose estimation, inversion, two concatenations, fusion
    both = merge([to_a, to_wt])
    assert len(both.components) == len(to_a.components | to_wt.components)
    assert len(both.components) < len(to_a.components) + len(to_wt.components)
    assert set(both.relations) == {"C->A:6D", "C->WT:6D"}


def test_data_flow_serialises_to_json(tracking_setup, templates):
    document = json.loads(json.dumps(flow_for(tracking_setup, templates).as_json()))
    assert len(document["components"]) == 6
    services = {c["service"] for c in document["components"]}
    assert services == {"pose_estimation_2d3d", "inversion", "concatenation", "fusion"}
    assert document["relations"]["C->A:6D"][1] == "AC"


def test_merge_keeps_both_computations_when_producers_differ(tracking_setup, templates):
    flow = flow_for(tracking_setup, templates)
    (fusion,) = by_pattern(flow)["MultiTrackerFusion"]
    # the same fusion fed by other producers in a second flow (e.g. another bracketing)
    other_inputs = tuple((port, Binding(None, f"other-{port}")) for port, _ in fusion.inputs)
    other = DataFlow(
        {fusion.id: replace(fusion, inputs=other_inputs)},
        {"C->WT:6D": Binding(fusion.id, "fused")},
    )
    merged = merge([flow, other])
    assert merged.components[fusion.id] == fusion
    renamed = merged.relations["C->WT:6D"].component
    assert renamed != fusion.id
    assert merged.components[renamed].inputs == other_inputs
    assert merged.relations["C->A:6D"] == flow.relations["C->A:6D"]


def test_plan_flows_serves_what_it_can_and_names_the_rest(tracking_setup, templates):
    queries = [QUERY, Query("C", "WT", "6D"), Query("WT", "IP", "3x4")]
    flow, unresolved = plan_flows(tracking_setup, templates, queries)
    assert set(flow.relations) == {"C->A:6D", "C->WT:6D"}
    assert list(unresolved) == ["WT->IP:3x4"]
    assert "no derivation of 3x4 WT->IP" in unresolved["WT->IP:3x4"]
    assert len(flow.components) == 6  # C->WT is shared with C->A
    lost = remove_provider(remove_provider(tracking_setup, "ART"), "C")
    _, unresolved = plan_flows(lost, templates, queries[:1])
    # without the tracker and the camera's features, only database edges remain around C
    assert unresolved["C->A:6D"].startswith("frames C and A are not connected")
    assert "C is connected to {C, HT, IP}" in unresolved["C->A:6D"]


def test_components_carry_the_planners_static_decision(
    tracking_setup, calibration_setup, templates
):
    """Static outputs are decided once, by the matcher, and travel with the component."""
    tracking = flow_for(tracking_setup, templates)
    assert all(not c.static_outputs for c in tracking.components.values())  # all dynamic
    query = Query("C", "HT", "6D", static=True)
    calibration = from_solution(plan(calibration_setup, templates, query)[0], query)
    producer = calibration.relations[relation_name(query)]
    assert producer.edge in calibration.components[producer.component].static_outputs
