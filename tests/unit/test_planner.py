"""The controller: best and all derivations, cost model, no-solution errors (sections 4, 5)."""

from __future__ import annotations

import itertools
import random
from collections import Counter
from dataclasses import replace
from pathlib import Path

import pytest
import yaml
from hypothesis import given, settings

from tests.unit import srg_strategies
from ubitrack_agent.graph.planner import (
    NoSolutionError,
    PlanningError,
    Query,
    introducible_frames,
    plan,
    relevant_frames,
    saturate,
    useful_types,
    with_solution,
)
from ubitrack_agent.graph.srg import load_setup, parse_setup

ROOT = Path(__file__).resolve().parents[2]


def signature(solution):
    """Steps as (pattern, expansion, sorted input triples, sorted output triples)."""
    return [
        (
            s["pattern"],
            s["expansion"],
            sorted(map(tuple, s["inputs"])),
            sorted(map(tuple, s["outputs"])),
        )
        for s in solution.as_json()["steps"]
    ]


def setup(*edges):
    return parse_setup(
        {"edges": [{"from": a, "to": b, "type": t, "static": s} for a, b, t, s in edges]}
    )


def test_best_tracking_solution_is_the_data_flow_of_figure_6(tracking_setup, templates):
    best = plan(tracking_setup, templates, Query("C", "A", "6D"))[0]
    steps = signature(best)
    assert Counter(p for p, *_ in steps) == {
        "PoseEstimation2D3D": 1,
        "Inversion": 1,
        "Concatenation": 3,
        "MultiTrackerFusion": 1,
    }
    pose = next(s for s in steps if s[0] == "PoseEstimation2D3D")
    assert pose[1] == "space" and pose[3] == [("C", "WT", "6D")]
    assert {("IP", f"F{i}", "2D") for i in range(1, 6)} <= set(pose[2])
    assert {("WT", f"F{i}", "3D") for i in range(1, 6)} <= set(pose[2])
    inversion = next(s for s in steps if s[0] == "Inversion")
    assert inversion[2] == [("ART", "HT", "6D")]
    concat_inputs = {t for p, _, ins, _ in steps if p == "Concatenation" for t in ins}
    assert {("C", "HT", "6D"), ("ART", "WT", "6D"), ("WT", "A", "6D")} <= concat_inputs
    fusion = next(s for s in steps if s[0] == "MultiTrackerFusion")
    assert fusion[1] == "space" and fusion[2] == [("C", "WT", "6D")] * 2
    assert steps[-1][0] == "Concatenation" and steps[-1][3] == [("C", "A", "6D")]
    assert ("C", "WT", "6D") in steps[-1][2]
    assert best.static is False


@pytest.mark.parametrize(
    ("setup_name", "query"),
    [
        ("tracking_setup", Query("C", "A", "6D")),
        ("calibration_setup", Query("C", "HT", "6D", static=True)),
    ],
)
def test_plans_depend_on_template_properties_not_on_pattern_names(
    request, templates, setup_name, query
):
    srg = request.getfixturevalue(setup_name)
    names = {t.pattern: f"P{i}" for i, t in enumerate(templates)}

    def renamed(template):
        inputs = tuple(
            replace(spec, not_from=frozenset(names[n] for n in spec.not_from))
            for spec in template.inputs
        )
        return replace(template, pattern=names[template.pattern], inputs=inputs)

    expected = [
        (round(s.cost, 9), [(names[p], *rest) for p, *rest in signature(s)])
        for s in plan(srg, templates, query)
    ]
    found = plan(srg, [renamed(t) for t in templates], query)
    assert [(round(s.cost, 9), signature(s)) for s in found] == expected


def test_fusion_beats_each_single_path(tracking_setup, templates):
    found = plan(tracking_setup, templates, Query("C", "A", "6D"))
    fused, *others = found
    assert others, "the single-path alternatives are listed too"
    assert all(fused.edge.quality.variance < o.edge.quality.variance for o in others)
    assert [s.cost for s in found] == sorted(s.cost for s in found)


def _kind(solution):
    patterns = [s["pattern"] for s in solution.as_json()["steps"]]
    if "HandEyeCalibration" in patterns:
        return "hand-eye"
    pose = next(s for s in solution.as_json()["steps"] if s["pattern"] == "PoseEstimation2D3D")
    frame = pose["outputs"][0][1]
    return {"WT": "direct", "HT": "pose-through-HT"}.get(frame, f"pose-through-{frame}")


def test_calibration_lists_the_three_solutions_of_section_4_2(calibration_setup, templates):
    found = plan(calibration_setup, templates, Query("C", "HT", "6D", static=True))
    assert all(s.static for s in found)
    kinds = {_kind(s): s for s in found}
    assert {"direct", "hand-eye", "pose-through-HT"} <= set(kinds)

    direct = signature(kinds["direct"])
    assert direct[0][:2] == ("PoseEstimation2D3D", "space")
    assert ("Inversion", "none", [("ART", "WT", "6D")], [("WT", "ART", "6D")]) in direct
    assert direct[-1][:2] == ("Averaging", "time")  # time-expanded fusion of C->HT estimates

    hand_eye = signature(kinds["hand-eye"])
    assert [p for p, *_ in hand_eye] == ["PoseEstimation2D3D", "HandEyeCalibration"]
    he = hand_eye[1]
    assert he[1] == "time"
    assert he[2] == [("ART", "HT", "6D"), ("C", "WT", "6D")]
    assert ("C", "HT", "6D") in he[3]  # and WT->ART, which is ignored

    through_ht = signature(kinds["pose-through-HT"])
    pose = next(s for s in through_ht if s[0] == "PoseEstimation2D3D")
    assert pose[1] == "space" and pose[3] == [("C", "HT", "6D")]
    assert {("HT", f"F{i}", "3D") for i in range(1, 6)} <= set(pose[2])
    assert through_ht[-1][:2] == ("Averaging", "time")


def test_dynamic_query_on_calibration_setup_has_no_calibration_steps(calibration_setup, templates):
    # without --static nothing says C-HT is rigid: only live chains through camera and tracker
    found = plan(calibration_setup, templates, Query("C", "HT", "6D"))
    patterns = {s["pattern"] for f in found for s in f.as_json()["steps"]}
    assert "PoseEstimation2D3D" in patterns
    assert not patterns & {"HandEyeCalibration", "Averaging"}
    assert not any(f.static for f in found)


def test_measured_edge_is_a_solution_without_steps(tracking_setup, templates):
    found = plan(tracking_setup, templates, Query("ART", "WT", "6D", static=True))
    assert found[0].steps == () and found[0].edge.measured


def test_no_redundant_derivations_on_a_triangle(templates):
    srg = setup(("A", "B", "6D", False), ("B", "C", "6D", False), ("A", "C", "6D", False))
    found = plan(srg, templates, Query("A", "C", "6D"))
    # the measured edge, the chain, and their fusion: nothing through C->A or B->A and back
    assert sorted(sorted(s.edge.sources) for s in found) == [
        ["A->B:6D", "A->C:6D", "B->C:6D"],
        ["A->B:6D", "B->C:6D"],
        ["A->C:6D"],
    ]


def test_no_step_inverts_an_inversion_or_reuses_a_measurement(tracking_setup, templates):
    frames = relevant_frames(tracking_setup, "C", "A", 2)
    ws = saturate(tracking_setup, templates, frames, "6D")
    edges = ws.index.edges
    for step in ws.steps.values():
        ids = [e for _, group in step.inputs for e in group]
        if step.template.pattern == "Inversion":
            assert edges[ids[0]].pattern not in ("Inversion", "Concatenation")
        if step.expansion != "space":
            for i, a in enumerate(ids):
                for b in ids[i + 1 :]:
                    assert not edges[a].sources & edges[b].sources


def test_disconnected_frames_are_named(templates):
    srg = setup(("A", "B", "6D", False), ("C", "D", "6D", False))
    with pytest.raises(NoSolutionError) as info:
        plan(srg, templates, Query("A", "D", "6D"))
    message = str(info.value)
    assert "A and D are not connected" in message
    assert "{A, B}" in message and "{C, D}" in message


def test_unknown_frame_is_named(templates):
    with pytest.raises(NoSolutionError, match="frame\\(s\\) Z not in the SRG"):
        plan(setup(("A", "B", "6D", False)), templates, Query("A", "Z", "6D"))


def test_connected_but_underivable(templates):
    srg = setup(("A", "B", "2D", False))
    with pytest.raises(NoSolutionError, match="no derivation of 6D A->B"):
        plan(srg, templates, Query("A", "B", "6D"))


def test_static_query_rejects_dynamic_only_results(templates):
    srg = setup(("A", "B", "6D", False), ("B", "C", "6D", True))
    found = plan(srg, templates, Query("A", "C", "6D", static=True))
    # only by averaging the dynamic chain over time (A-C declared rigid by the query)
    assert all(s.static for s in found)
    assert found[0].as_json()["steps"][-1]["pattern"] == "Averaging"


def test_bad_queries():
    with pytest.raises(PlanningError, match="unknown type"):
        Query("A", "B", "5D")
    with pytest.raises(PlanningError, match="different frames"):
        Query("A", "A", "6D")
    with pytest.raises(ValueError, match="frame name"):
        Query("A b", "B", "6D")


def test_useful_types_prune_rotations_for_pose_queries(templates):
    assert "3R" not in useful_types(templates, "6D")
    assert {"6D", "3D", "2D", "3x4"} <= useful_types(templates, "6D")
    assert "6D" in useful_types(templates, "3R")


def test_relevant_frames_drop_pendant_frames(calibration_setup):
    frames = relevant_frames(calibration_setup, "C", "HT", 2)
    assert "A" not in frames  # WT->A hangs off the world target: on no C-HT path
    assert {"C", "IP", "WT", "ART", "HT", "F1", "F5"} <= frames


def test_sensor_quality_drives_the_choice(templates):
    def srg(sigma_b):
        return parse_setup(
            {
                "edges": [
                    {"from": "A", "to": "B", "type": "6D", "sigma": 0.001, "provider": "t1"},
                    {"from": "A", "to": "B", "type": "6D", "sigma": sigma_b, "provider": "t2"},
                ]
            }
        )

    # two equal trackers: fusing them halves the variance and is worth the second sensor
    best = plan(srg(0.001), templates, Query("A", "B", "6D"))[0]
    assert best.as_json()["steps"][0]["pattern"] == "MultiTrackerFusion"
    assert best.edge.quality.variance == pytest.approx(0.5e-6)
    # a much worse second tracker: fusion gains little, the single good tracker wins
    best = plan(srg(0.01), templates, Query("A", "B", "6D"))[0]
    assert best.steps == () and best.edge.provider == "t1"


def test_fusion_of_paths_of_different_lengths_is_found(templates):
    # s-a-t and the longer s-b-c-t: the goal-directed concatenation rule keeps both chains
    srg = setup(
        ("s", "a", "6D", False),
        ("a", "t", "6D", False),
        ("b", "s", "6D", False),
        ("b", "c", "6D", False),
        ("t", "c", "6D", False),
    )
    found = plan(srg, templates, Query("s", "t", "6D"))
    best = found[0].as_json()["steps"]
    assert best[-1]["pattern"] == "MultiTrackerFusion"
    assert len(found[0].edge.sources) == 5
    assert sorted(len(s.edge.sources) for s in found) == [2, 3, 5]


def test_with_solution_adds_the_inferred_edges_with_provenance(tracking_setup, templates):
    best = plan(tracking_setup, templates, Query("C", "A", "6D"))[0]
    graph = with_solution(tracking_setup, best)
    inferred = [d for _, _, d in graph.edges(data=True) if not d["measured"]]
    assert len(inferred) == len(best.steps) == 6
    assert {d["derivation"] for d in inferred} == {s.id for s in best.steps}
    fused = next(d for d in inferred if d["provider"] == "fusion")
    assert fused["sources"] == best.edge.sources - {"WT->A:6D"}
    assert tracking_setup.number_of_edges() + 6 == graph.number_of_edges()


def test_plan_does_not_depend_on_the_order_of_the_setup_edges(templates):
    data = yaml.safe_load((ROOT / "examples" / "paper_tracking.yaml").read_text())
    for entry in data["edges"]:
        entry["id"] = f"{entry['from']}->{entry['to']}"
    reference = None
    for seed in range(4):
        random.Random(seed).shuffle(data["edges"])
        found = plan(parse_setup(data), templates, Query("C", "A", "6D"))
        document = [s.as_json() for s in found]
        reference = reference or document
        assert document == reference


def test_alternatives_per_relation_are_bounded(templates):
    edges = [("A", "B", "6D", False)] * 10 + [("B", "C", "6D", True)]
    srg = setup(*edges)
    ws = saturate(srg, templates, {"A", "B", "C"}, "6D", per_relation=3, goal=("A", "C"))
    derived = ws.by_relation[("A", "C", "6D", False)]
    assert 1 <= len(derived) <= 3
    assert ws.index.retired  # cheaper alternatives (fusions) replaced the first ones
    best = plan(srg, templates, Query("A", "C", "6D"), per_relation=3)[0]
    fusion = next(s for s in best.steps if s.template.pattern == "MultiTrackerFusion")
    assert len(dict(fusion.inputs)["AB"]) == 10  # all ten trackers fused in one step


@settings(max_examples=40, deadline=None)
@given(edges=srg_strategies.edges, query=srg_strategies.queries)
def test_any_srg_gets_valid_solutions_or_a_clear_error(templates, edges, query):
    srg = setup(*((f"N{a}", f"N{b}", t, s) for a, b, t, s in edges))
    q = Query(f"N{query[0]}", f"N{query[1]}", "6D", query[2])
    try:
        found = plan(srg, templates, q)
    except NoSolutionError as exc:
        assert str(exc)
        return
    for solution in found:
        assert (solution.edge.source, solution.edge.target, solution.edge.type) == (
            q.source,
            q.target,
            "6D",
        )
        assert solution.static or not q.static
        for step in solution.steps:
            ids = [e for _, group in step.inputs for e in group]
            records = [solution.records[e] for e in ids]
            if step.template.pattern == "Inversion":
                assert records[0].pattern != "Inversion"
            if step.expansion != "space":
                for i, a in enumerate(records):
                    for b in records[i + 1 :]:
                        assert a.sources.isdisjoint(b.sources) or (
                            a.time_integrated or b.time_integrated
                        )


# --- a frame introduced by a calibration: the pointer's tip --------------------------------------

POINTER = (("T", "M", "6D", False), ("T", "B", "6D", False))
"""A tracker T following a pointer's marker M and another body B; the tip is no frame yet."""


def test_a_static_query_to_a_new_frame_plans_the_tip_calibration(templates):
    srg = setup(*POINTER)
    (solution,) = plan(srg, templates, Query("M", "Tip", "3D", static=True))
    (step,) = solution.steps
    assert (step.template.pattern, step.expansion) == ("TipCalibration", "time")
    assert dict(step.inputs) == {"TM": ("T->M:6D",)}
    added = {(src, dst): edge_id for _, src, dst, _, edge_id in step.outputs}
    assert added[("M", "Tip")] == solution.edge.id
    assert added[("T", "Tip")] is None  # the pivot: Tip is fixed in T only while calibrating
    graph = with_solution(srg, solution)
    assert [(u, v) for u, v, d in graph.edges(data=True) if not d["measured"]] == [("M", "Tip")]


def test_the_pivot_is_the_static_relation_of_the_tracker_to_the_new_frame(templates):
    found = plan(setup(*POINTER), templates, Query("T", "Tip", "3D", static=True))
    # either body may be the one pivoting: both are derivations, each adding only T->Tip; they
    # are not fused (each calibration defines Tip: they may have calibrated different points)
    assert sorted(dict(s.steps[0].inputs)["TM"] for s in found) == [("T->B:6D",), ("T->M:6D",)]
    for solution in found:
        outputs = {(src, dst): edge_id for _, src, dst, _, edge_id in solution.steps[0].outputs}
        assert outputs[("T", "Tip")] == solution.edge.id
        assert list(outputs.values()).count(None) == 1


def test_a_tip_on_a_marker_rigidly_mounted_on_the_pointer(templates):
    srg = setup(*POINTER, ("M", "N", "6D", True))
    best = plan(srg, templates, Query("N", "Tip", "3D", static=True))[0]
    assert [s.template.pattern for s in best.steps] == ["Concatenation", "TipCalibration"]
    assert dict(best.steps[-1].inputs)["TM"] == (best.steps[0].outputs[0][4],)  # T->N


def test_a_new_frame_needs_a_static_query_and_a_calibration_that_yields_it(templates):
    srg = setup(*POINTER)
    with pytest.raises(NoSolutionError, match="frame\\(s\\) Tip not in the SRG \\(a calibration"):
        plan(srg, templates, Query("T", "Tip", "3D"))  # which body's tip: not said
    message = "no derivation of static 6D M->Tip: frame Tip is not in the SRG and no calibration"
    with pytest.raises(NoSolutionError, match=message):
        plan(srg, templates, Query("M", "Tip", "6D", static=True))  # a point has no orientation
    with pytest.raises(NoSolutionError, match="frame\\(s\\) Tip, X not in the SRG"):
        plan(srg, templates, Query("Tip", "X", "3D", static=True))
    without = [t for t in templates if not t.introduced]
    with pytest.raises(NoSolutionError, match=r"^frame\(s\) Tip not in the SRG$"):
        plan(srg, without, Query("M", "Tip", "3D", static=True))


def test_introducible_frames_and_their_neighbourhood(templates):
    srg = setup(("A", "B", "6D", False), ("B", "C", "6D", False), ("C", "D", "6D", False))
    assert introducible_frames(srg, templates, Query("A", "Tip", "3D", static=True)) == ("Tip",)
    assert introducible_frames(srg, templates, Query("Tip", "A", "3D", static=True)) == ("Tip",)
    assert introducible_frames(srg, templates, Query("A", "Tip", "3D")) == ()
    assert introducible_frames(srg, templates, Query("A", "D", "3D", static=True)) == ()
    assert introducible_frames(srg, templates, Query("X", "Tip", "3D", static=True)) == ()
    # the new frame counts as one hop from A: frames within slack + 1 hops take part
    assert relevant_frames(srg, "A", "Tip", 1, ("Tip",)) == {"A", "B", "C"}
    with pytest.raises(NoSolutionError, match="frame\\(s\\) Tip not in the SRG"):
        relevant_frames(srg, "A", "Tip", 1)


@pytest.mark.parametrize("name", ["paper_tracking", "paper_calibration"])
def test_a_pattern_introducing_frames_changes_no_plan_between_frames_of_the_srg(templates, name):
    srg = load_setup(ROOT / "examples" / f"{name}.yaml")
    without = [t for t in templates if not t.introduced]

    def documents(catalogue, query):
        try:
            return [s.as_json() for s in plan(srg, catalogue, query)]
        except NoSolutionError as exc:
            return str(exc)

    for source, target in itertools.permutations(sorted(srg.nodes), 2):
        for edge_type in ("6D", "3D"):
            query = Query(source, target, edge_type, static=True)  # time-only patterns run
            assert documents(templates, query) == documents(without, query), query
