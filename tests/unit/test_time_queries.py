"""Queries for a value at a given time (``net.time_queries``) and how a latest-value publisher
answers them: typed errors across the wire, hostile times rejected and counted."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
from hypothesis import given
from hypothesis import strategies as st

from ubitrack_agent.core.errors import ExtrapolationError, NoDataError, NoMotionModel
from ubitrack_agent.net.encodings import MSGPACK
from ubitrack_agent.net.time_queries import (
    error_payload,
    raise_error,
    requested_time,
    selector,
)
from ubitrack_agent.net.transport import LatestValuePublisher


def test_selector_and_requested_time():
    assert selector("a/b", 12) == "a/b?t=12"
    assert requested_time({"t": "12"}) == 12
    assert requested_time({}) is None
    for bad in ("-1", "1e9", "abc", "", "9" * 20, "99999999999999999999"):
        with pytest.raises(ValueError):
            requested_time({"t": bad})


@pytest.mark.parametrize(
    "error",
    [
        ExtrapolationError("far"),
        NoMotionModel("measured"),
        NoDataError("none"),
        TimeoutError("slow"),
        ValueError("x"),
    ],
)
def test_errors_keep_their_type_across_the_wire(error):
    with pytest.raises(type(error), match=f"key: {error}") as raised:
        raise_error(error_payload(error), "key")
    assert type(raised.value) is type(error)


@given(st.text(max_size=30))
def test_requested_time_is_total(text):
    try:
        value = requested_time({"t": text})
    except ValueError:
        return
    assert value is not None and 0 <= value < 2**63 and value == int(text)


def test_a_reply_that_is_no_error_object_reads_as_no_answer():
    for payload in (b"Timeout", b'{"error": "unknown", "message": "m"}', b"[1]", b"\xff"):
        with pytest.raises(NoDataError):
            raise_error(payload, "key")


class FakeQuery:
    def __init__(self, parameters: dict[str, str]) -> None:
        self.parameters = parameters
        self.replies: list[bytes] = []
        self.errors: list[bytes] = []

    def reply(
        self, key: str, payload: bytes, encoding: object = None, attachment: object = None
    ) -> None:
        assert encoding == MSGPACK  # a measurement
        self.replies.append(payload)

    def reply_err(self, payload: bytes) -> None:
        self.errors.append(payload)


def publisher(at=None) -> LatestValuePublisher:
    session = SimpleNamespace(
        declare_publisher=lambda key, encoding, congestion_control: SimpleNamespace(
            put=lambda data, attachment: None,
            undeclare=lambda: None,
            matching_status=SimpleNamespace(matching=False),
            declare_matching_listener=lambda callback: SimpleNamespace(undeclare=lambda: None),
        ),
        declare_queryable=lambda key, handler: SimpleNamespace(undeclare=lambda: None),
    )
    return LatestValuePublisher(session, "k", at)


def answer(publisher_: LatestValuePublisher, parameters: dict[str, str]) -> FakeQuery:
    query = FakeQuery(parameters)
    publisher_._reply(query)
    return query


def test_publisher_answers_latest_times_and_typed_errors():
    def at(t: int) -> bytes:
        if t > 100:
            raise ExtrapolationError("beyond")
        if t < 10:
            raise NoDataError("before")
        return str(t).encode()

    timed = publisher(at)
    timed.put(b"latest")
    assert answer(timed, {}).replies == [b"latest"]
    assert answer(timed, {"t": "50"}).replies == [b"50"]
    for t, error in (("500", ExtrapolationError), ("5", NoDataError)):
        (payload,) = answer(timed, {"t": t}).errors
        with pytest.raises(error):
            raise_error(payload, "k")
    (payload,) = answer(timed, {"t": "soon"}).errors
    with pytest.raises(ValueError):
        raise_error(payload, "k")
    assert timed.counters["rejected_queries"] == 1
    untimed = publisher()
    untimed.put(b"latest")
    (payload,) = answer(untimed, {"t": "50"}).errors
    with pytest.raises(NoMotionModel, match="latest value only"):
        raise_error(payload, "k")
