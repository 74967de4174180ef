"""Calibration progress on the wire: round trips, and total parsing of hostile input."""

from __future__ import annotations

import contextlib
import json

import pytest
from hypothesis import given
from hypothesis import strategies as st

from ubitrack_agent.commands.calibrate import advice, describe
from ubitrack_agent.net.json_messages import MessageError, field, load_object
from ubitrack_agent.net.progress import Progress, ProgressError, parse_progress

GOOD = Progress(
    instance="averaging-1",
    status="averaging",
    accepted=120,
    rejected=3,
    timestamp_ns=10**18,
    std_translation=0.002,
    std_rotation=0.001,
    tolerance_translation=0.001,
    tolerance_rotation=0.002,
    value={"type": "Position3D", "timestamp_ns": 10**18, "position": [0.0, 0.1, 1.0]},
)


def test_round_trip_and_fraction_done():
    assert parse_progress(GOOD.to_json().encode()) == GOOD
    assert GOOD.fraction_done() == pytest.approx(0.5)  # translation: 1 mm of 2 mm
    converged = Progress("a", "converged", 60, 0, 1)
    assert converged.converged and converged.fraction_done() == 1.0
    assert Progress("a", "initialising", 3, 0, 1).fraction_done() == 0.0


@pytest.mark.parametrize(
    "change, message",
    [
        ({"status": "done"}, "status: expected one of"),
        ({"accepted": -1}, "must be in [0, 2^63)"),
        ({"accepted": True}, "accepted: expected int"),
        ({"std_rotation": "small"}, "std_rotation: expected float"),
        ({"instance": "a/b"}, "must not contain '/'"),
        ({"colour": "red"}, "unknown fields ['colour']"),
        ({"value": [1, 2]}, "value: expected dict"),
        ({"timestamp_ns": 2**63}, "must be in [0, 2^63)"),
        ({"std_rotation": 10**400}, "std_rotation: expected float"),  # beyond any float
    ],
)
def test_malformed_progress_names_the_field(change, message):
    data = {**json.loads(GOOD.to_json()), **change}
    with pytest.raises(ProgressError) as info:
        parse_progress(json.dumps(data).encode())
    assert message in str(info.value)


def test_non_finite_numbers_are_refused():
    text = GOOD.to_json().replace('"std_rotation": 0.001', '"std_rotation": NaN')
    with pytest.raises(ProgressError, match="std_rotation"):
        parse_progress(text.encode())


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner),
    max_leaves=20,
)


@given(st.binary(max_size=200) | json_values.map(lambda v: json.dumps(v).encode()))
def test_any_payload_gives_a_progress_or_a_progress_error(payload):
    with contextlib.suppress(ProgressError):  # the only exception it may raise
        assert isinstance(parse_progress(payload), Progress)


@pytest.mark.parametrize(
    "payload, error",
    [
        (None, "malformed_request"),
        (b"[" * 100_000 + b"]" * 100_000, "oversized_request"),
        (b"[" * 5000 + b"]" * 5000, "malformed_request"),  # nested too deeply
        (b'{"a": ' + b"[" * 40 + b"]" * 40 + b"}", "malformed_request"),  # beyond MAX_DEPTH
        (b"\xff", "malformed_request"),
        (b"[1]", "malformed_request"),
    ],
)
def test_load_object_is_total(payload, error):
    with pytest.raises(MessageError) as info:
        load_object(payload, 64 * 1024)
    assert info.value.error == error


def test_field_checks_kinds_exactly():
    assert field({"n": 3}, "n", float) == 3.0
    for data, kind in (
        ({"n": True}, int),
        ({"n": float("inf")}, float),
        ({"n": 10**400}, float),
        ({}, str),
    ):
        with pytest.raises(MessageError):
            field(data, "n", kind)
    assert field({}, "n", str, optional=True) is None


def test_advice_and_progress_line_for_people():
    line = describe(GOOD, "C", "HT")
    assert "[##########----------]  50%" in line and "120 samples, 3 rejected" in line
    assert "2.00 mm" in line and "keep C and HT measured" in line
    flaky = Progress("a", "averaging", 50, 40, 1)
    assert "many samples rejected" in advice(flaky, "C", "HT")
