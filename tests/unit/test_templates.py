"""Template service descriptions: schema, validation and the shipped catalogue (section 3)."""

from __future__ import annotations

import copy

import pytest

from ubitrack_agent.graph.templates import (
    Multiplicity,
    TemplateError,
    load_template,
    load_templates,
    parse_template,
)

POSE_2D3D = {
    "pattern": "PoseEstimation2D3D",
    "service": "pose_estimation_2d3d",
    "roles": ["C", "I", "O", "F"],
    "inputs": [
        {"name": "CI", "from": "C", "to": "I", "type": "3x4"},
        {"name": "IF", "from": "I", "to": "F", "type": "2D"},
        {"name": "OF", "from": "O", "to": "F", "type": "3D"},
    ],
    "outputs": [{"name": "CO", "from": "C", "to": "O", "type": "6D"}],
    "correspondence": {
        "edges": ["IF", "OF"],
        "multiplicity": "4..*",
        "expansions": ["space", "time"],
        "expand_roles": ["F"],
    },
}


PAPER_PATTERNS = {
    "Inversion",
    "Concatenation",
    "MultiTrackerFusion",
    "PoseEstimation3D3D",
    "PoseEstimation2D3D",
    "ProjectiveCalibration2D3D",
    "Triangulation2D3D",
    "HandEyeCalibration",
    "Averaging",
    "Auxiliary",
}
"""The patterns of the paper's catalogue (sections 3.1, 3.4, 4.3) that ship as templates."""

UBITRACK_PATTERNS = {"TipCalibration"}
"""Patterns shipped beyond the paper's catalogue, after Ubitrack's components."""


def test_shipped_catalogue_covers_every_pattern(templates):
    assert {t.pattern for t in templates} == PAPER_PATTERNS | UBITRACK_PATTERNS
    assert len({t.service for t in templates}) == len(templates)
    signatures = {t.pattern: t.signature for t in templates}
    assert signatures.pop("Inversion") == "inverse"
    assert signatures.pop("Concatenation") == "chain"
    assert set(signatures.values()) == {"step"}


def test_templates_are_generic_over_types(templates):
    by_name = {t.name: t for t in templates}
    concat = by_name["concatenation"]
    assert concat.type_vars == {"T": ("6D", "3D")}
    assert concat.outputs[0].type == "$T"
    assert set(by_name["fusion"].type_vars["T"]) == {"6D", "3D", "3R"}


def test_correspondence_of_2d3d_pose_estimation(templates):
    pose = next(t for t in templates if t.pattern == "PoseEstimation2D3D")
    corr = pose.correspondence
    assert corr.edges == ("IF", "OF")
    assert corr.expand_roles == ("F",)
    assert corr.expansions == {"space", "time"}
    assert 4 in corr.multiplicity and 3 not in corr.multiplicity and 1000 in corr.multiplicity


def test_hand_eye_is_time_only_with_static_outputs(templates):
    hand_eye = next(t for t in templates if t.pattern == "HandEyeCalibration")
    assert hand_eye.time_only
    assert all(o.static is True for o in hand_eye.outputs)


def test_only_the_tip_calibration_introduces_a_frame(templates):
    introducing = {t.pattern: t.introduced for t in templates if t.introduced}
    assert introducing == {"TipCalibration": ("P",)}
    tip = next(t for t in templates if t.pattern == "TipCalibration")
    assert tip.time_only and [o.name for o in tip.outputs] == ["MP", "TP"]


def test_a_frame_is_introduced_only_by_a_time_only_pattern():
    data = copy.deepcopy(POSE_2D3D)
    data["roles"].append("X")
    data["outputs"].append({"name": "CX", "from": "C", "to": "X", "type": "3D"})
    with pytest.raises(TemplateError) as info:
        parse_template(data, "templates/pose.yaml")
    assert str(info.value) == (
        "templates/pose.yaml: field 'roles': X bound by no input: only a time-only pattern "
        "(a calibration, correspondence expansions [time]) may introduce a frame"
    )
    data["correspondence"]["expansions"] = ["time"]
    assert parse_template(data).introduced == ("X",)


def test_parse_and_load_round_trip(tmp_path):
    import yaml

    path = tmp_path / "pose.yaml"
    path.write_text(yaml.safe_dump(POSE_2D3D))
    template = load_template(path)
    assert template.name == "pose"
    assert template.service == "pose_estimation_2d3d"
    assert template.inputs[0].static is None
    assert template.host_labels == frozenset()
    assert parse_template({**POSE_2D3D, "host_labels": ["gpu", "camera"]}).host_labels == {
        "gpu",
        "camera",
    }
    assert template.isolation == "shared"  # a container shared with its derivation
    assert parse_template({**POSE_2D3D, "isolation": "own"}).isolation == "own"


@pytest.mark.parametrize(
    ("text", "lo", "hi"), [("4..*", 4, None), ("2..5", 2, 5), ("3", 3, 3), (6, 6, 6)]
)
def test_multiplicity_syntax(text, lo, hi):
    data = copy.deepcopy(POSE_2D3D)
    data["correspondence"]["multiplicity"] = text
    assert parse_template(data).correspondence.multiplicity == Multiplicity(lo, hi)


def _broken(path: str, value):
    data = copy.deepcopy(POSE_2D3D)
    *parents, last = path.split(".")
    target = data
    for key in parents:
        target = target[int(key)] if key.isdigit() else target[key]
    if value is KeyError:
        del target[last]
    else:
        target[last] = value
    return data


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        ("color", "red", "top level: unknown field(s) ['color']"),
        ("pattern", "magic pattern", "field 'pattern': 'magic pattern' is not well-formed"),
        ("signature", "twisted", "field 'signature': 'twisted' is not one of"),
        ("signature", "inverse", "field 'signature': an inverse has exactly one input"),
        ("inputs.0.not_from", ["no-pattern"], "inputs[0].not_from[0]: 'no-pattern' is not"),
        ("service", "ubitrack_agent.services.pose:Estimator", "field 'service'"),
        ("service", KeyError, "missing field 'service'"),
        ("inputs.0.type", "$T", "type variable $T is not declared"),
        ("inputs.1.type", "4D", "inputs[1].type: '4D' is not one of"),
        ("inputs.1.from", "X", "inputs[1].from: 'X' is not one of"),
        ("inputs.0.static", "yes", "inputs[0].static: must be true or false"),
        ("inputs.0.mode", "poll", "inputs[0].mode"),
        ("inputs.0.extra", 1, "inputs[0]: unknown field(s) ['extra']"),
        ("outputs.0.name", "CI", "duplicate edge name 'CI'"),
        ("correspondence.edges", ["IF", "XX"], "correspondence.edges: 'XX' is not one of"),
        ("correspondence.multiplicity", "4..2", "is empty"),
        ("correspondence.multiplicity", "many", "is not a multiplicity"),
        ("correspondence.expansions", ["space", "warp"], "'warp' is not one of"),
        ("correspondence.expansions", [], "must list space and/or time"),
        ("correspondence.expand_roles", ["C"], "must not use a role of expand_roles"),
        ("cost", {"rule": "magic"}, "cost.rule"),
        ("roles", ["C", "C"], "duplicate entries"),
        ("host_labels", "gpu", "field 'host_labels': must be a list"),
        ("host_labels", ["gpu", "a b"], "field 'host_labels'[1]: 'a b' is not well-formed"),
        ("host_labels", ["gpu", "gpu"], "duplicate entries"),
        ("isolation", "alone", "field 'isolation': 'alone' is not one of ['own', 'shared']"),
        ("isolation", True, "field 'isolation': True is not one of"),
        ("isolation", ["own"], "field 'isolation': ['own'] is not one of"),
        ("signature", {"step": 1}, "field 'signature': {'step': 1} is not one of"),
    ],
)
def test_invalid_templates_name_file_entry_and_field(path, value, message):
    with pytest.raises(TemplateError) as info:
        parse_template(_broken(path, value), "templates/pose.yaml")
    assert str(info.value).startswith("templates/pose.yaml: ")
    assert message in str(info.value)


def test_output_type_variable_must_be_bound_by_an_input():
    data = {
        "pattern": "Inversion",
        "service": "inversion",
        "type_vars": {"T": ["6D"], "U": ["3D"]},
        "roles": ["A", "B"],
        "inputs": [{"name": "AB", "from": "A", "to": "B", "type": "$T"}],
        "outputs": [{"name": "BA", "from": "B", "to": "A", "type": "$U"}],
    }
    with pytest.raises(TemplateError, match=r"outputs\[0\].type: type variable \$U is bound by no"):
        parse_template(data)


def test_not_from_names_a_pattern_of_the_loaded_set(tmp_path):
    import yaml

    data = copy.deepcopy(POSE_2D3D)
    data["inputs"][0]["not_from"] = ["PoseEstimation2D3D", "Inversion"]
    (tmp_path / "pose.yaml").write_text(yaml.safe_dump(data))
    with pytest.raises(TemplateError) as info:
        load_templates(tmp_path)
    assert str(info.value) == (
        f"{tmp_path / 'pose.yaml'}: inputs[0].not_from: Inversion is the pattern of no loaded "
        "template (loaded: PoseEstimation2D3D)"
    )
    inversion = {
        "pattern": "Inversion",
        "service": "inversion",
        "roles": ["A", "B"],
        "inputs": [{"name": "AB", "from": "A", "to": "B", "type": "6D"}],
        "outputs": [{"name": "BA", "from": "B", "to": "A", "type": "6D"}],
    }
    (tmp_path / "inversion.yaml").write_text(yaml.safe_dump(inversion))
    pose = next(t for t in load_templates(tmp_path) if t.name == "pose")
    assert pose.inputs[0].not_from == {"PoseEstimation2D3D", "Inversion"}


def test_empty_template_directory_is_an_error(tmp_path):
    with pytest.raises(TemplateError, match=r"no \*\.yaml template files"):
        load_templates(tmp_path)
