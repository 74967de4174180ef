"""An input's ``clock_offset_ns`` (``net/spec.py``): parsed and written symmetrically (omitted
when 0), bounded to a day either way, hostile values refused with the field named, and changed
in place by a rewire (``agent/reconcile.py``)."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.integration.fuzz_inputs import HOSTILE_NUMBERS
from ubitrack_agent.agent.reconcile import control_command
from ubitrack_agent.net.config import MAX_CLOCK_OFFSET_NS
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.spec import ComponentSpec, InputBinding, SpecError, parse_spec

KEYS = KeySpace("ubitrack/test")
SPEC = ComponentSpec(
    instance="fusion-1",
    service="fusion",
    inputs=(
        InputBinding("AB", KEYS.data("ART/HT"), trigger=True),
        InputBinding("AB", KEYS.data("cam/HT"), trigger=True, clock_offset_ns=-300_000_000),
    ),
    outputs={"AB": KEYS.data("fusion-1/AB")},
)


def test_an_offset_is_written_when_set_and_reads_back():
    wire = SPEC.as_dict()["inputs"]
    assert "clock_offset_ns" not in wire[0]
    assert wire[1]["clock_offset_ns"] == -300_000_000
    assert parse_spec(SPEC.to_json()) == SPEC


@pytest.mark.parametrize("offset", [0, 1, -MAX_CLOCK_OFFSET_NS, MAX_CLOCK_OFFSET_NS])
def test_offsets_within_a_day_are_accepted(offset):
    data = SPEC.as_dict()
    data["inputs"][0]["clock_offset_ns"] = offset
    spec = parse_spec(json.dumps(data))
    assert spec.inputs[0].clock_offset_ns == offset
    assert parse_spec(spec.to_json()) == spec


@given(
    HOSTILE_NUMBERS
    | st.sampled_from([MAX_CLOCK_OFFSET_NS + 1, -MAX_CLOCK_OFFSET_NS - 1, 2**63, True, 1.5, 3e8])
)
def test_hostile_offsets_are_refused_naming_the_field(offset):
    data = SPEC.as_dict()
    data["inputs"][1]["clock_offset_ns"] = offset
    with pytest.raises(SpecError, match=r"inputs\[1\]\.clock_offset_ns"):
        parse_spec(json.dumps(data))


def test_a_new_offset_is_a_rewire_in_place():
    first = replace(SPEC.inputs[0], clock_offset_ns=250_000)
    corrected = replace(SPEC, inputs=(first, SPEC.inputs[1]))
    command = control_command(SPEC, corrected)
    assert command == {"inputs": corrected.as_dict()["inputs"]}
    assert command["inputs"][0]["clock_offset_ns"] == 250_000
