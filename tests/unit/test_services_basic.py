"""Registry, component specifications, and the inversion and concatenation services."""

import json
import sys
import textwrap

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ubitrack_agent.core import ErrorPose, Pose, Position2D, Position3D, Projection, Rotation3D, se3
from ubitrack_agent.net.spec import SpecError, parse_spec
from ubitrack_agent.services import components, registry
from ubitrack_agent.services.registry import lookup
from ubitrack_agent.services.spec import check_spec

RNG = np.random.default_rng(5)
Q = Rotation.random(rng=RNG).as_quat()
T = RNG.normal(size=3)
K = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])


def test_lookup_lists_known_services_when_unknown():
    assert lookup("concatenation").NAME == "concatenation"
    with pytest.raises(KeyError, match=r"known:.*inversion"):
        lookup("os.system")


EXTRA_MODULE = """
from ubitrack_agent.services.registry import Port, Service, register
from ubitrack_agent.core import Pose


@register
class Extra(Service):
    NAME = "extra_for_discovery_test"
    INPUTS = {"AB": Port((Pose,))}
    OUTPUTS = ("BA",)

    def compute(self, values, timestamp_ns):
        return {}
"""


def test_component_modules_are_discovered_without_a_list(tmp_path, monkeypatch):
    registry.load_components()  # the shipped services, in the registry the test leaves as it was
    (tmp_path / "extra_for_discovery_test.py").write_text(textwrap.dedent(EXTRA_MODULE))
    monkeypatch.setattr(components, "__path__", [*components.__path__, str(tmp_path)])
    monkeypatch.setattr(registry, "SERVICES", dict(registry.SERVICES))
    registry.load_components.cache_clear()
    try:
        assert lookup("extra_for_discovery_test").__module__ == (
            "ubitrack_agent.services.components.extra_for_discovery_test"
        )
    finally:
        sys.modules.pop("ubitrack_agent.services.components.extra_for_discovery_test", None)
        registry.load_components.cache_clear()


def test_inversion_of_pose_and_rotation():
    service = lookup("inversion")({})
    out = service.compute({"AB": ErrorPose(1, Q, T, np.eye(6) * 1e-6)}, 1)["BA"]
    back = se3.compose(Q, T, out.rotation, out.translation)
    np.testing.assert_allclose(se3.to_matrix(*back), np.eye(4), atol=1e-12)
    rotation = service.compute({"AB": Rotation3D(1, Q)}, 1)["BA"]
    np.testing.assert_allclose(rotation.rotation, Q * [-1, -1, -1, 1])


def test_concatenation_of_every_supported_pair():
    service = lookup("concatenation")({})
    pose = Pose(7, Q, T)
    point = Position3D(7, [0.1, 0.2, 3.0])
    out = service.compute({"AB": pose, "BC": point}, 7)["AC"]
    np.testing.assert_allclose(out.position, se3.transform_points(Q, T, point.position))
    rot = service.compute({"AB": Rotation3D(7, Q), "BC": Rotation3D(7, Q)}, 7)["AC"]
    assert isinstance(rot, Rotation3D)
    projection = Projection(7, K @ np.hstack((np.eye(3), np.zeros((3, 1)))))
    composed = service.compute({"AB": projection, "BC": pose}, 7)["AC"]
    np.testing.assert_allclose(composed.matrix, projection.matrix @ se3.to_matrix(Q, T))
    pixel = service.compute({"AB": projection, "BC": point}, 7)["AC"]
    assert isinstance(pixel, Position2D)
    np.testing.assert_allclose(pixel.position, [320 + 800 * 0.1 / 3, 240 + 800 * 0.2 / 3])
    with pytest.raises(ValueError, match="cannot concatenate"):
        service.compute({"AB": Rotation3D(7, Q), "BC": pose}, 7)
    behind = Position3D(7, [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="infinity"):
        service.compute({"AB": projection, "BC": behind}, 7)


def test_unknown_parameters_are_refused():
    with pytest.raises(ValueError, match="unknown parameters"):
        lookup("inversion")({"gain": 2})


VALID = {
    "instance": "c1",
    "service": "concatenation",
    "inputs": [
        {"port": "AB", "key": "u/d/data/A/B", "static": True},
        {"port": "BC", "key": "u/d/data/B/C", "trigger": True},
    ],
    "outputs": {"AC": "u/d/data/c1/AC"},
}


def test_valid_spec_round_trips_through_json():
    spec = parse_spec(json.dumps(VALID))
    assert spec.tolerance_ns == 5_000_000
    assert spec.required_providers == spec.required_edges == ()
    assert parse_spec(spec.to_json()) == spec
    edges = ["u/d/data/art/ART_HT", "u/d/data/cam/F"]
    needing = parse_spec({**VALID, "required_providers": ["art", "cam"], "required_edges": edges})
    assert needing.required_providers == ("art", "cam")
    assert needing.required_edges == tuple(edges)
    assert parse_spec(needing.to_json()) == needing


@pytest.mark.parametrize(
    "change, fragment",
    [
        ({"service": "subprocess"}, "spec.service: no registered service"),
        ({"instance": "a/b"}, "spec.instance"),
        ({"instance": 5}, "spec.instance: expected str"),
        ({"outputs": {"nope": "k"}}, "has no output 'nope'"),
        ({"outputs": {"AC": "u/*/x"}}, "spec.outputs.AC"),
        ({"inputs": [{**VALID["inputs"][0], "trigger": True}]}, "port 'BC' needs exactly one"),
        ({"inputs": [VALID["inputs"][0], {**VALID["inputs"][1], "trigger": False}]}, "trigger"),
        ({"inputs": [VALID["inputs"][0], {**VALID["inputs"][1], "key": "a/**"}]}, "inputs[1].key"),
        ({"inputs": [VALID["inputs"][0], {**VALID["inputs"][1], "extra": 1}]}, "unknown fields"),
        ({"inputs": "x"}, "expected a list"),
        ({"tolerance_ms": -1}, "tolerance_ms"),
        ({"tolerance_ms": True}, "tolerance_ms"),
        ({"colour": "red"}, "unknown fields ['colour']"),
        ({"expansion": "sideways"}, "spec.expansion: must be one of"),
        ({"expansion": "space"}, "concatenation has no correspondence"),
        ({"time_expansion": {"min_motion": 1}}, "only for expansion 'time'"),
        ({"required_edges": "u/d/data/a/b"}, "spec.required_edges: expected a list"),
        ({"required_edges": ["u/d/data/a/b", 5]}, "spec.required_edges[1]: expected a string"),
        ({"required_edges": ["u/d/data/*/b"]}, "spec.required_edges[0]"),
        ({"required_edges": ["u/d/data/a/b"] * 1001}, "at most 1000"),
        ({"required_providers": "art"}, "spec.required_providers: expected a list"),
        ({"required_providers": ["art", 5]}, "spec.required_providers[1]: expected a string"),
        ({"required_providers": ["a/b"]}, "spec.required_providers[0]"),
        ({"required_providers": ["x"] * 1001}, "at most 1000"),
    ],
)
def test_invalid_specs_name_the_field(change, fragment):
    with pytest.raises(SpecError) as info:
        check_spec(parse_spec({**VALID, **change}))
    assert fragment in str(info.value)


def test_spec_text_must_be_a_json_object():
    with pytest.raises(SpecError, match="not JSON"):
        parse_spec("{")
    with pytest.raises(SpecError, match="expected a JSON object"):
        parse_spec("[1]")
