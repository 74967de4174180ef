"""The agent's pure parts: fragments, planning every relation, specifications, reconciling."""

import json

import pytest

from ubitrack_agent.agent.announcements import AnnouncementError, build_srg, fragment_entries
from ubitrack_agent.agent.flows import HYSTERESIS, Plan, plan_name, plan_relations
from ubitrack_agent.agent.materialise import component_specs
from ubitrack_agent.agent.reconcile import reconcile
from ubitrack_agent.graph.dataflow import DataFlow, from_solution, relation_name
from ubitrack_agent.graph.planner import Query, plan
from ubitrack_agent.graph.templates import load_templates
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.spec import parse_spec

KEYS = KeySpace("ubitrack/test")
TEMPLATES = load_templates()


def fragment(provider, *edges):
    return json.dumps({"provider": provider, "edges": list(edges)}).encode()


def edge(name, source, target, edge_type="6D", **extra):
    return {"name": name, "from": source, "to": target, "type": edge_type, **extra}


def paper_fragments():
    """The paper's tracking setup (figure 1) as three providers."""
    features = [f"F{i}" for i in range(1, 6)]
    return {
        "art": fragment_entries(
            "art",
            fragment("art", edge("HT", "ART", "HT", rate=60), edge("WT", "ART", "WT", static=True)),
        ),
        "camera": fragment_entries(
            "camera", fragment("camera", *(edge(f, "IP", f, "2D", rate=30) for f in features))
        ),
        "database": fragment_entries(
            "database",
            fragment(
                "database",
                edge("C_HT", "C", "HT", static=True),
                edge("C_IP", "C", "IP", "3x4", static=True),
                edge("WT_A", "WT", "A", static=True),
                *(edge(f"WT_{f}", "WT", f, "3D", static=True) for f in features),
            ),
        ),
    }


def test_fragment_entries_carry_ids_and_providers():
    entries = fragment_entries("art", fragment("art", edge("HT", "ART", "HT", sigma=0.001)))
    assert entries == [
        {
            "from": "ART",
            "to": "HT",
            "type": "6D",
            "sigma": 0.001,
            "id": "art/HT",
            "provider": "art",
        }
    ]
    hosted = json.dumps({"provider": "art", "host": "room", "edges": [edge("HT", "ART", "HT")]})
    (entry,) = fragment_entries("art", hosted.encode())
    assert entry["host"] == "room"
    srg = build_srg({"art": [entry]})
    assert srg.edges["ART", "HT", "art/HT"]["host"] == "room"


@pytest.mark.parametrize(
    "payload, fragment_text",
    [
        (b"{", "not JSON"),
        (b"[]", "expected a JSON object"),
        (fragment("other", edge("HT", "ART", "HT")), "names provider 'other'"),
        (fragment("art"), "1 to"),
        (fragment("art", edge("HT", "ART", "HT", colour=1)), "unknown fields ['colour']"),
        (fragment("art", edge("H/T", "ART", "HT")), "name"),
        (fragment("art", edge("HT", "A*", "HT")), "from"),
        (fragment("art", edge("HT", "ART", "HT", "7D")), "unknown type"),
        (fragment("art", edge("HT", "ART", "HT", rate=-1)), "in [0, 100000], got -1"),
        (fragment("art", edge("HT", "ART", "HT"), edge("HT", "ART", "WT")), "duplicate"),
        (b"x" * (2 << 20), "at most 1048576"),
        (b'{"provider": "art", "host": "a/b", "edges": []}', "host: "),
        (b'{"provider": "art", "host": "", "edges": []}', "host: "),
        (b'{"provider": "art", "host": ["room"], "edges": []}', "host: "),
        (b'{"provider": "art", "room": "x", "edges": []}', "host"),
    ],
)
def test_malformed_fragments_are_rejected_with_the_reason(payload, fragment_text):
    with pytest.raises(AnnouncementError) as info:
        fragment_entries("art", payload)
    assert "provider 'art'" in str(info.value)
    assert fragment_text in str(info.value)


def specs_for(fragments, *relations):
    srg = build_srg(fragments)
    plan = plan_relations(srg, TEMPLATES, relations)
    return plan, component_specs(plan.flow, srg, KEYS, plan.relations)


def test_paper_setup_becomes_figure_6_workers():
    wanted = RelationId("C", "A", "6D")
    plan, specs = specs_for(paper_fragments(), wanted)
    assert not plan.unsolved
    services = sorted(spec.service for spec in specs.values())
    assert services == sorted(
        [
            "pose_estimation_2d3d",
            "inversion",
            "concatenation",
            "concatenation",
            "fusion",
            "concatenation",
        ]
    )
    for spec in specs.values():
        assert parse_spec(spec.to_json()) == spec  # every spec is one a worker accepts
    pnp = next(s for s in specs.values() if s.service == "pose_estimation_2d3d")
    assert pnp.expansion == "space"
    assert [b.port for b in pnp.inputs].count("IF") == 5
    assert {b.key for b in pnp.inputs if b.port == "CI"} == {KEYS.data("database/C_IP")}
    assert all(b.trigger and not b.static for b in pnp.inputs if b.port == "IF")
    assert all(b.static and not b.trigger for b in pnp.inputs if b.port in ("CI", "OF"))
    final = [s for s in specs.values() if s.relations]
    assert len(final) == 1 and final[0].service == "concatenation"
    assert final[0].relations == {"AC": (KEYS.relation(wanted),)}


def test_each_component_names_the_providers_and_edges_it_computes_nothing_without():
    wanted = RelationId("C", "A", "6D")
    _, specs = specs_for(paper_fragments(), wanted)
    needed = {spec.service: set() for spec in specs.values()}
    for spec in specs.values():
        needed[spec.service] |= {(spec.required_providers, spec.required_edges)}
    # the camera, but no one of its five features (each binding needs its own); static C_IP
    # and WT_F nothing
    assert needed["pose_estimation_2d3d"] == {(("camera",), ())}
    art = (("art",), (KEYS.data("art/HT"),))  # the fragment names its edge HT
    assert needed["inversion"] == {art}
    assert needed["concatenation"] == {art, ((), ())}  # the ART branch, and after the fusion
    assert needed["fusion"] == {((), ())}  # each estimate it fuses needs another provider
    (producer,) = [s for s in specs.values() if s.relations]
    assert (producer.required_providers, producer.required_edges) == ((), ())
    fragments = paper_fragments()
    del fragments["camera"]
    _, art_only = specs_for(fragments, wanted)
    (producer,) = [s for s in art_only.values() if s.relations]
    assert (producer.required_providers, producer.required_edges) == art
    _, relayed = specs_for(fragments, RelationId("ART", "HT", "6D"))
    (relay,) = relayed.values()
    assert relay.service == "relay"
    assert (relay.required_providers, relay.required_edges) == art


def test_missing_frames_and_measured_relations():
    fragments = paper_fragments()
    plan, specs = specs_for(fragments, RelationId("C", "Z", "6D"), RelationId("ART", "HT", "6D"))
    assert "no provider announces frame(s) Z" in plan.unsolved["C->Z:6D"]
    (relay,) = specs.values()
    assert relay.service == "relay"
    assert relay.inputs[0].key == KEYS.data("art/HT")
    assert relay.relations == {"out": (KEYS.relation(RelationId("ART", "HT", "6D")),)}


def test_losing_the_tracker_replaces_the_fused_flow():
    wanted = RelationId("C", "A", "6D")
    fragments = paper_fragments()
    _, before = specs_for(fragments, wanted)
    del fragments["art"]
    _, after = specs_for(fragments, wanted)
    actions = reconcile(before, after)
    assert {spec.instance for spec in actions.start} == set(after) - set(before)
    assert set(actions.stop) == set(before) - set(after)
    assert not any("art/" in b.key for spec in after.values() for b in spec.inputs)
    (producer,) = [s for s in after.values() if s.relations]
    assert list(producer.relations.values()) == [(KEYS.relation(wanted),)]
    assert reconcile(before, before).empty


def test_a_second_relation_reroutes_a_running_component_in_place():
    _, one = specs_for(paper_fragments(), RelationId("C", "A", "6D"))
    _, two = specs_for(paper_fragments(), RelationId("C", "A", "6D"), RelationId("C", "WT", "6D"))
    actions = reconcile(one, two)
    assert not actions.stop
    updated = dict(actions.update)
    assert any(set(command) == {"relations"} for command in updated.values())


def test_shared_components_between_relations():
    _, one = specs_for(paper_fragments(), RelationId("C", "A", "6D"))
    _, both = specs_for(paper_fragments(), RelationId("C", "A", "6D"), RelationId("C", "WT", "6D"))
    assert set(one) <= set(both)
    routed = [s for s in both.values() if s.relations]
    assert len(routed) == 2


def test_restart_needed_when_more_than_wiring_changes():
    _, specs = specs_for(paper_fragments(), RelationId("C", "A", "6D"))
    instance, spec = next(iter(specs.items()))
    from dataclasses import replace

    changed = {instance: replace(spec, expansion="time" if spec.expansion != "time" else "none")}
    actions = reconcile({instance: spec}, changed)
    assert actions.stop == (instance,) and actions.start == (changed[instance],)


def test_replanning_keeps_a_relations_running_derivation_within_the_margin():
    """Without the A.R.T. tracker, C->A by pose estimation on the marker balls expressed in A
    costs 1.5 % more than pose estimation of C->WT then WT->A: whichever runs for C->A stays."""
    wanted = RelationId("C", "A", "6D")
    fragments = paper_fragments()
    del fragments["art"]
    srg = build_srg(fragments)
    query = Query("C", "A", "6D")
    first, second = plan(srg, TEMPLATES, query)[:2]
    assert first.cost < second.cost <= first.cost * (1 + HYSTERESIS)
    cheapest = set(from_solution(first, query).components)
    running = set(from_solution(second, query).components)
    assert cheapest != running
    previous = Plan(DataFlow(), kept={relation_name(query): frozenset(running)})
    stable = plan_relations(srg, TEMPLATES, [wanted], running, previous)
    assert set(stable.flow.components) == running
    assert set(plan_relations(srg, TEMPLATES, [wanted]).flow.components) == cheapest


def live_like_fragments():
    """The paper's setup with the live sigmas (A.R.T. 0.3 mm, camera about 1.4 mm at 2 m), the
    database without C->HT and a calibration store that holds it."""
    fragments = paper_fragments()
    features = [f"F{i}" for i in range(1, 6)]
    fragments["art"] = fragment_entries(
        "art",
        fragment(
            "art",
            edge("HT", "ART", "HT", rate=60, sigma=3e-4),
            edge("WT", "ART", "WT", static=True, sigma=3e-4),
        ),
    )
    fragments["camera"] = fragment_entries(
        "camera",
        fragment("camera", *(edge(f, "IP", f, "2D", rate=30, sigma=1.4e-3) for f in features)),
    )
    database = [e for e in fragments["database"] if e["id"] != "database/C_HT"]
    stored = edge("C_HT", "C", "HT", static=True, sigma=1.1e-3)  # as a converged calibration
    store = fragment_entries("store", fragment("store", stored))
    return {**fragments, "database": database}, store


def test_a_new_relation_is_not_pulled_onto_another_relations_components():
    """After a live C->HT calibration, its running inversion and concatenations make the
    A.R.T.-only path to C->A cheap to start and within the margin of fusion; a new C->A query
    still gets fusion (the cheapest), and keeps it on the next replan."""
    fragments, store = live_like_fragments()
    calibration = RelationId("C", "HT", "6D", static=True)
    calibrating = plan_relations(build_srg(fragments), TEMPLATES, [calibration])
    running = set(calibrating.flow.components)
    srg = build_srg({**fragments, "store": store})
    tracking = RelationId("C", "A", "6D")
    cheapest = plan_relations(srg, TEMPLATES, [tracking])
    assert "fusion" in {c.service for c in cheapest.flow.components.values()}
    adopting = plan_relations(srg, TEMPLATES, [tracking], running)  # no plan yet: all count
    assert "fusion" not in {c.service for c in adopting.flow.components.values()}
    fresh = plan_relations(srg, TEMPLATES, [tracking], running, previous=calibrating)
    assert "fusion" in {c.service for c in fresh.flow.components.values()}
    again = plan_relations(srg, TEMPLATES, [tracking], set(fresh.flow.components), fresh)
    assert set(again.flow.components) == set(fresh.flow.components)


RECALIBRATE_C_HT = RelationId("C", "HT", "6D", static=True, recalibrate=True)


def keys_read(specs):
    return {binding.key for spec in specs.values() for binding in spec.inputs}


def test_a_recalibration_ignores_the_stored_edge_the_other_queries_keep_using():
    stored = KEYS.data("database/C_HT")
    _, alone = specs_for(paper_fragments(), RECALIBRATE_C_HT)
    assert stored not in keys_read(alone)
    (recalibration,) = [s for s in alone.values() if s.relations]
    assert recalibration.service == "averaging" and recalibration.expansion == "time"
    assert recalibration.relations == {"mean": (KEYS.relation(RECALIBRATE_C_HT),)}

    static, tracking = RelationId("C", "HT", "6D", static=True), RelationId("C", "A", "6D")
    plan, specs = specs_for(paper_fragments(), RECALIBRATE_C_HT, static, tracking)
    assert not plan.unsolved
    assert plan.relations["C->HT:6D/recalibrate"] == RECALIBRATE_C_HT
    assert specs[recalibration.instance] == recalibration  # shares the others' components
    assert keys_read(alone) <= keys_read(specs)
    (relay,) = [s for s in specs.values() if s.service == "relay"]
    assert relay.inputs[0].key == stored and relay.relations == {"out": (KEYS.relation(static),)}
    readers = [s.service for s in specs.values() if stored in {b.key for b in s.inputs}]
    assert sorted(readers) == ["concatenation", "relay"]  # the tracking chain still uses it


def test_a_recalibration_with_no_other_derivation_is_unsolved_saying_why():
    fragments = {"database": paper_fragments()["database"]}
    plan, specs = specs_for(fragments, RECALIBRATE_C_HT, RelationId("C", "HT", "6D", True))
    reason = plan.unsolved["C->HT:6D/recalibrate"]
    assert reason.startswith("without the measured static edge(s) database/C_HT: ")
    assert "HT" in reason
    (relay,) = specs.values()  # the static relation is still served from the stored edge
    assert relay.relations == {"out": (KEYS.relation(RelationId("C", "HT", "6D", True)),)}


def test_a_stored_tip_is_calibrated_again_on_request():
    fragments = {
        "tracker": fragment_entries("tracker", fragment("tracker", edge("M", "T", "M", rate=60))),
        "store.M_Tip": fragment_entries(
            "store.M_Tip", fragment("store.M_Tip", edge("M_Tip", "M", "Tip", "3D", static=True))
        ),
    }
    recalibration = RelationId("M", "Tip", "3D", static=True, recalibrate=True)
    plan, specs = specs_for(fragments, recalibration)
    assert not plan.unsolved
    (calibration,) = [s for s in specs.values() if s.relations]
    assert calibration.service == "tip_calibration"
    assert KEYS.relation(recalibration) in calibration.relations["MP"]


def test_plan_names_keep_a_recalibration_apart():
    assert plan_name(RelationId("C", "A", "6D")) == "C->A:6D"
    assert plan_name(RelationId("C", "HT", "6D", static=True)) == "C->HT:6D/static"
    assert plan_name(RECALIBRATE_C_HT) == "C->HT:6D/recalibrate"
    plan, _ = specs_for(paper_fragments(), RelationId("C", "HT", "7D", True, True))
    assert "unknown type '7D'" in plan.unsolved["C->HT:7D recalibrate"]


def test_only_static_inputs_given_without_a_rate_have_a_fixed_error():
    """The database's calibrations and survey (static, no rate) are fixed errors, marked for
    the fusion to consider; the tracker's static body, measured again at its rate, is not (a
    new error in every sample); dynamic inputs never are."""
    fragments = paper_fragments()
    fragments["art"] = fragment_entries(
        "art",
        fragment(
            "art",
            edge("HT", "ART", "HT", rate=60),
            edge("WT", "ART", "WT", static=True, rate=60),
        ),
    )
    _, specs = specs_for(fragments, RelationId("C", "A", "6D"))
    fixed = {b.key for s in specs.values() for b in s.inputs if b.fixed_error}
    static = {b.key for s in specs.values() for b in s.inputs if b.static}
    assert KEYS.data("art/WT") in static - fixed
    assert {KEYS.data("database/C_HT"), KEYS.data("database/WT_A")} <= fixed
    assert fixed <= static
    _, unrated = specs_for(paper_fragments(), RelationId("C", "A", "6D"))  # WT without a rate
    assert KEYS.data("art/WT") in {
        b.key for s in unrated.values() for b in s.inputs if b.fixed_error
    }
