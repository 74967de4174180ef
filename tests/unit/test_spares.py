"""Spare derivations (``agent/spares.py``): the flow a relation falls back on when a sensor of
its chosen derivation is lost, planned beside it, its producer on the relation's key too."""

from __future__ import annotations

import pytest
import yaml

from tests.unit.conftest import ROOT
from ubitrack_agent.agent.flows import plan_relation
from ubitrack_agent.agent.materialise import component_specs, relay_instance
from ubitrack_agent.agent.placement import group_containers
from ubitrack_agent.agent.spares import MAX_REPLICAS, Redundancy, sensors, spare_solutions
from ubitrack_agent.graph.dataflow import Binding, DataFlow, merge
from ubitrack_agent.graph.planner import Query, plan
from ubitrack_agent.graph.srg import parse_setup
from ubitrack_agent.net.keys import RelationId

C_A = RelationId("C", "A", "6D")
BETTER_TRACKER = [
    {"from": "ART", "to": "ART2", "type": "6D", "static": True},
    {"from": "ART2", "to": "HT", "type": "6D", "provider": "ART2", "sigma": 3e-4},
    {"from": "ART2", "to": "WT", "type": "6D", "provider": "ART2", "sigma": 3e-4},
]
"""A second outside-in tracker in the paper's room (figure 1), more precise than the A.R.T.
tracker (the switch benchmark's "better tracker")."""


def paper_room(*extra: dict) -> object:
    data = yaml.safe_load((ROOT / "examples" / "paper_tracking.yaml").read_text())
    data["edges"] += list(extra)
    return parse_setup(data)


class Keys:
    def data(self, edge_id: str) -> str:
        return f"data/{edge_id}"

    def relation(self, relation: RelationId) -> str:
        return f"relation/{relation}"


@pytest.fixture(scope="module")
def three_sensors(templates):
    srg = paper_room(*BETTER_TRACKER)
    return srg, plan(srg, templates, Query("C", "A", "6D"))


def test_the_spare_of_the_better_tracker_is_the_fusion_of_the_two_sensors_left(three_sensors):
    _, solutions = three_sensors
    chosen = solutions[0]
    assert sensors(chosen) == {"C", "ART2"}  # the camera fused with the better tracker
    (spare,) = spare_solutions(chosen, solutions)
    assert sensors(spare) == {"C", "ART"}  # what is best without ART2, and reads ART
    # Without the camera the best is the better tracker alone: nothing the chosen flow does
    # not read (its fusion on standby computes that), so no spare for the camera.
    without_camera = next(s for s in solutions if "C" not in sensors(s))
    assert sensors(without_camera) == {"ART2"}


def test_a_derivation_reading_every_sensor_an_alternative_reads_has_no_spare(
    tracking_setup, templates
):
    solutions = plan(tracking_setup, templates, Query("C", "A", "6D"))
    assert sensors(solutions[0]) == {"C", "ART"}  # figure 6: both fused
    assert spare_solutions(solutions[0], solutions) == []
    part = plan_relation(tracking_setup, templates, C_A)
    assert part.flow.spares == {} and set(part.flow.components) == part.serving


def test_a_spare_is_planned_with_the_relation_and_puts_on_its_key(three_sensors, templates):
    srg, _ = three_sensors
    part = plan_relation(srg, templates, C_A)
    (spare,) = part.flow.spares["C->A:6D"]
    primary = part.flow.relations["C->A:6D"]
    assert spare.component not in part.serving and primary.component in part.serving
    assert set(part.flow.components) > part.serving  # the spare's own components besides
    assert any(edge.startswith("ART->HT") for edge in part.edges)  # losing A.R.T. replans it
    specs = component_specs(part.flow, srg, Keys(), part.relations)
    key = Keys().relation(C_A)
    on_key = {i for i, spec in specs.items() if any(key in ks for ks in spec.relations.values())}
    assert on_key == {primary.component, spare.component}


def test_an_agent_without_spares_plans_none(three_sensors, templates):
    srg, _ = three_sensors
    part = plan_relation(srg, templates, C_A, redundancy=Redundancy(spares=False))
    assert part.flow.spares == {} and set(part.flow.components) == part.serving


def test_the_spare_becomes_the_derivation_with_the_same_components_when_its_sensor_is_lost(
    three_sensors, templates
):
    srg, _ = three_sensors
    before = plan_relation(srg, templates, C_A)
    (spare,) = before.flow.spares["C->A:6D"]
    without = srg.copy()
    without.remove_edges_from(
        [(u, v, k) for u, v, k, p in srg.edges(keys=True, data="provider") if p == "ART2"]
    )
    after = plan_relation(without, templates, C_A)
    assert after.flow.relations["C->A:6D"] == spare  # the running spare's producer
    assert after.serving <= set(before.flow.components)  # nothing new to start


def test_merging_flows_keeps_each_spare_producer_once():
    one = DataFlow(spares={"C->A:6D": (Binding("x", "AC"),)})
    two = DataFlow(spares={"C->A:6D": (Binding("x", "AC"), Binding("y", "AC"))})
    merged = merge([one, two])
    assert merged.spares == {"C->A:6D": (Binding("x", "AC"), Binding("y", "AC"))}
    assert merged.as_json()["spares"] == {"C->A:6D": [["x", "AC"], ["y", "AC"]]}


def test_a_replica_is_the_same_derivation_under_other_ids_and_puts_on_the_key_too(
    tracking_setup, templates
):
    alone = plan_relation(tracking_setup, templates, C_A)
    part = plan_relation(tracking_setup, templates, C_A, redundancy=Redundancy(replicas=2))
    assert part.serving == alone.serving  # the chosen derivation is the same
    (primary,), replicas = [part.flow.relations["C->A:6D"]], part.flow.spares["C->A:6D"]
    assert len(replicas) == 2 and primary not in replicas
    copies = set(part.flow.components) - part.serving
    assert len(copies) == 2 * len(part.serving)  # two copies, every component its own id
    services = [part.flow.components[i].service for i in part.serving]
    assert sorted(part.flow.components[i].service for i in copies) == sorted(services * 2)
    assert part.kept == set(part.flow.components)  # what a later choice keeps running
    specs = component_specs(part.flow, tracking_setup, Keys(), part.relations)
    key = Keys().relation(C_A)
    on_key = {i for i, spec in specs.items() if any(key in ks for ks in spec.relations.values())}
    assert on_key == {primary.component, *(r.component for r in replicas)}


def test_a_relation_read_from_a_measured_edge_has_no_replica(tracking_setup, templates):
    measured = RelationId("ART", "HT", "6D")
    part = plan_relation(tracking_setup, templates, measured, redundancy=Redundancy(replicas=1))
    assert part.unsolved is None and part.flow.components == {} and part.flow.spares == {}


@pytest.mark.parametrize("replicas", [-1, MAX_REPLICAS + 1])
def test_replicas_beyond_the_bounds_are_refused(replicas):
    with pytest.raises(ValueError, match="replicas: expected 0 to"):
        Redundancy(replicas=replicas)


@pytest.mark.parametrize("cores", [2, 1])
def test_copies_of_a_derivation_run_in_different_containers(tracking_setup, templates, cores):
    part = plan_relation(tracking_setup, templates, C_A, redundancy=Redundancy(replicas=1))
    specs = component_specs(part.flow, tracking_setup, Keys(), part.relations)
    hosts = dict.fromkeys(specs, "room")
    groups = group_containers(specs, hosts, {"room": cores})
    assert sorted(groups) == ["room-0", "room-1"]  # on one core, the second is opened for it
    (primary,) = [n for n, g in groups.items() if {s.instance for s in g.components} & part.serving]
    assert {s.instance for s in groups[primary].components} == part.serving
    current = {s.instance: name for name, g in groups.items() for s in g.components}
    assert group_containers(specs, hosts, {"room": cores}, current=current) == groups  # stable


def test_a_spare_read_from_a_measured_edge_is_put_by_the_relay_named_for_it(tracking_setup):
    edge = next(
        key
        for *_, key, data in tracking_setup.edges(keys=True, data=True)
        if not data.get("static")
    )
    flow = DataFlow(spares={"C->A:6D": (Binding(None, edge),)})
    specs = component_specs(flow, tracking_setup, Keys(), {"C->A:6D": C_A})
    (relay,) = specs.values()
    assert relay.instance == relay_instance(edge) and relay.service == "relay"
    assert relay.relations == {"out": (Keys().relation(C_A),)}
