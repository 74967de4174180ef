"""The host manager protocol and keys: round trips, and every malformed message refused with
its type (``ubitrack_agent/net/host_protocol.py``)."""

import json
from dataclasses import replace

import pytest
from hypothesis import given
from hypothesis import strategies as st

from ubitrack_agent.net.host_protocol import (
    ERRORS,
    MAX_MESSAGE_BYTES,
    Exited,
    HostInfo,
    ProtocolError,
    Start,
    Started,
    StartedGroup,
    StartGroup,
    Status,
    Stop,
    encode_request,
    parse_request,
)
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.spec import ComponentSpec, GroupSpec, InputBinding

KEYS = KeySpace("ubitrack/test")
SPEC = ComponentSpec(
    instance="relay-1",
    service="relay",
    inputs=(InputBinding("in", KEYS.data("art/HT"), trigger=True),),
    outputs={"out": KEYS.data("relay-1/out")},
)


@pytest.mark.parametrize(
    "request_", [Start(SPEC), StartGroup(GroupSpec("lab-0", (SPEC,))), Stop("relay-1"), Status()]
)
def test_requests_round_trip(request_):
    assert parse_request(encode_request(request_).encode()) == request_


def test_replies_and_reports_round_trip():
    started = Started("relay-1", "0123abcd", 42, reused=False)
    assert Started.parse(started.to_json().encode()) == started
    group = StartedGroup("lab-0", 42, (started, Started("b", "r2", 42, reused=True)))
    assert StartedGroup.parse(group.to_json().encode()) == group
    for exited in (
        Exited("relay-1", "0123abcd", 42, -9, "exited"),
        Exited("relay-1", "0123abcd", 42, None, "released"),
        Exited("relay-1", "0123abcd", 43, -9, "restored"),
    ):
        assert Exited.parse(exited.to_json().encode()) == exited
    refusal = ProtocolError("refused_spec", "spec.service: no registered service 'x'")
    parsed = ProtocolError.parse(refusal.to_json().encode())
    assert (parsed.error, parsed.reason) == (refusal.error, refusal.reason)


@pytest.mark.parametrize(
    ("payload", "error", "fragment"),
    [
        (None, "malformed_request", "empty"),
        (b"", "malformed_request", "empty"),
        (b"{not json", "malformed_request", "not JSON"),
        (b"\xff\xfe", "malformed_request", "UTF-8"),
        (b"[" * 100_000 + b"]" * 100_000, "malformed_request", "nested"),
        (b"[]", "malformed_request", "object"),
        (b" " * (MAX_MESSAGE_BYTES + 1), "oversized_request", "bytes"),
        (b'{"op": 5}', "malformed_request", "op"),
        (b'{"op": "reboot"}', "malformed_request", "op"),
        (b'{"op": "status", "also": 1}', "malformed_request", "exactly"),
        (b'{"op": "stop", "instance": ["a"]}', "malformed_request", "instance"),
        (b'{"op": "stop", "instance": "a/b"}', "malformed_request", "instance"),
        (b'{"op": "stop", "instance": "**"}', "malformed_request", "instance"),
        (b'{"op": "start", "spec": "x"}', "malformed_request", "spec"),
        (b'{"op": "start", "spec": {"instance": "a"}}', "refused_spec", "spec."),
        (b'{"op": "start_group", "group": []}', "malformed_request", "group"),
        (b'{"op": "start_group", "group": {"container": "a/b"}}', "refused_spec", "container"),
        (
            json.dumps(
                {
                    "op": "start_group",
                    "group": {"container": "c", "components": [SPEC.as_dict()] * 2},
                }
            ).encode(),
            "refused_spec",
            "twice",
        ),
    ],
)
def test_malformed_requests_are_refused_with_their_type(payload, error, fragment):
    with pytest.raises(ProtocolError) as refused:
        parse_request(payload)
    assert refused.value.error == error
    assert fragment in refused.value.reason


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=10),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner),
    max_leaves=30,
)


@given(
    st.dictionaries(
        st.sampled_from(["op", "spec", "instance", "x"]) | st.text(max_size=5), json_values
    )
    | json_values
)
def test_parse_request_raises_nothing_but_protocol_errors(data):
    payload = json.dumps(data).encode()
    try:
        parse_request(payload)
    except ProtocolError as refusal:
        assert refusal.error in ERRORS


@given(st.binary(max_size=200))
def test_parse_request_is_total_over_bytes(payload):
    try:
        parse_request(payload)
    except ProtocolError as refusal:
        assert refusal.error in ERRORS


@pytest.mark.parametrize(
    "report",
    [
        {"instance": "a", "run": "r", "pid": 1, "returncode": "1", "reason": "exited"},
        {"instance": "a", "run": "r", "pid": True, "returncode": 0, "reason": "exited"},
        {"instance": "a", "run": "r", "pid": 1, "returncode": 0, "reason": "bored"},
        {"instance": "a/*", "run": "r", "pid": 1, "returncode": 0, "reason": "exited"},
    ],
)
def test_malformed_exit_reports_are_refused(report):
    with pytest.raises(ProtocolError):
        Exited.parse(json.dumps(report).encode())


def test_host_keys_and_their_parsers():
    assert KEYS.host("lab-pc") == "ubitrack/test/host/lab-pc"
    assert KEYS.host_request("lab-pc") == "ubitrack/test/host/lab-pc/request"
    assert KEYS.host_exited("lab-pc") == "ubitrack/test/host/lab-pc/exited"
    assert KEYS.parse_host(KEYS.host("lab-pc")) == "lab-pc"
    assert KEYS.parse_host_exited(KEYS.host_exited("lab-pc")) == "lab-pc"
    assert KEYS.parse_pool(KEYS.pool("ab-12")) == "ab-12"
    assert KEYS.parse_worker(KEYS.worker("concat-1", "42.a1b2")) == ("concat-1", "42.a1b2")
    assert KEYS.parse_container(KEYS.container("lab-0", "42.a1b2")) == ("lab-0", "42.a1b2")
    assert KEYS.parse_container_left(KEYS.container_left("lab-0")) == "lab-0"
    with pytest.raises(ValueError):
        KEYS.parse_container_left(KEYS.container_left("lab-0") + "/x")


@pytest.mark.parametrize(
    "key",
    [
        "ubitrack/test/host/a/b",
        "ubitrack/test/host/",
        "ubitrack/test/host/*",
        "ubitrack/other/host/a",
        "ubitrack/test/hosts/a",
        "ubitrack/test/host/a b",
    ],
)
def test_malformed_host_keys_are_rejected(key):
    with pytest.raises(ValueError):
        KEYS.parse_host(key)


@pytest.mark.parametrize(
    "key",
    ["ubitrack/test/host/a/exit", "ubitrack/test/host/a/b/exited", "ubitrack/test/host/exited"],
)
def test_malformed_exit_keys_are_rejected(key):
    with pytest.raises(ValueError):
        KEYS.parse_host_exited(key)


@pytest.mark.parametrize("name", ["a/b", "*", "a b", "", "h$"])
def test_hostile_host_names_are_rejected(name):
    with pytest.raises(ValueError):
        KEYS.host(name)


def test_host_information_round_trips_through_the_status_reply():
    info = HostInfo("hmd", frozenset({"camera", "hmd"}), 12, 0.25, cores=3, isolating=True)
    instances = {
        "a": {"run": "r1", "pid": 7, "container": "hmd-0"},
        "b": {"run": "r2", "pid": 8, "container": None},
    }
    status = {**info.as_dict(), "pid": 7, "instances": instances, "counters": {}, "clock": None}
    parsed = HostInfo.parse(json.dumps(status).encode())
    assert parsed == info and parsed.cores == 3 and parsed.isolating
    assert parsed.runs == {"a": ("r1", 7, "hmd-0"), "b": ("r2", 8, None)}
    older = {k: v for k, v in status.items() if k not in ("cores", "isolating")}  # before them
    assert HostInfo.parse(json.dumps(older).encode()) == replace(info, cores=1, isolating=False)


GOOD_INFO = {"name": "hmd", "labels": ["camera"], "capacity": 4, "cpu_load": 0.5}


@pytest.mark.parametrize(
    "change",
    [
        {"labels": "camera"},
        {"labels": ["a b"]},
        {"labels": [f"l{i}" for i in range(33)]},
        {"labels": [["camera"]]},
        {"capacity": 0},
        {"capacity": 10**30},
        {"capacity": 4.0},
        {"capacity": True},
        {"cpu_load": -1},
        {"cpu_load": "high"},
        {"cpu_load": None},
        {"cpu_load": float("inf")},
        {"cpu_load": float("nan")},
        {"name": "*"},
        {"instances": []},
        {"instances": {"a b": {"run": "r", "pid": 1}}},
        {"instances": {"a": {"run": "r"}}},
        {"instances": {"a": {"run": "r/*", "pid": 1}}},
        {"instances": {"a": 5}},
        {"instances": {"a": {"run": "r", "pid": 1, "container": "x/*"}}},
        {"cores": 0},
        {"cores": 2.0},
        {"cores": 10**6},
        {"isolating": 1},
    ],
)
def test_malformed_host_information_is_refused(change):
    with pytest.raises(ProtocolError):
        HostInfo.parse(json.dumps({**GOOD_INFO, **change}).encode())


@given(
    st.dictionaries(
        st.sampled_from(["name", "labels", "capacity", "cpu_load"]) | st.text(max_size=5),
        json_values,
    )
)
def test_parsing_host_information_raises_nothing_but_protocol_errors(data):
    try:
        HostInfo.parse(json.dumps({**GOOD_INFO, **data}).encode())
    except ProtocolError as refusal:
        assert refusal.error in ERRORS
