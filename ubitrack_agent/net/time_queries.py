"""Asking a key for its value at a given time (the pull side of a relation).

A query ``<key>?t=<ns>`` asks the producer publishing on ``<key>`` (a worker's output key or
a relation key) for the value at ``t`` nanoseconds: a worker answers by interpolation of its
inputs, from its filter's motion model for the near future (at most
:data:`ubitrack_agent.core.timeline.MAX_AHEAD_NS` after the newest measurement), or by asking
its own inputs' producers the same question (``ubitrack_agent.services.worker``). A reply is the
encoded measurement stamped ``t`` (``core.codec``), or an error reply: a JSON object ``{"error":
<kind>, "message": <text>}`` whose kind names the typed exception the asker raises
(:data:`ERRORS`). A query without ``t`` gets the latest value, as before
(:class:`ubitrack_agent.net.transport.LatestValuePublisher`).
"""

from __future__ import annotations

import json
from typing import Any, NoReturn

from ubitrack_agent.core.errors import ExtrapolationError, NoDataError, NoMotionModel
from ubitrack_agent.core.measurements import check_timestamp
from ubitrack_agent.net.address import is_misaddressed

TIME_PARAMETER = "t"
"""The selector parameter carrying the time asked for (integer nanoseconds)."""

ERRORS: dict[str, type[Exception]] = {
    "no_model": NoMotionModel,
    "extrapolation": ExtrapolationError,
    "no_data": NoDataError,
    "timeout": TimeoutError,
    "invalid": ValueError,
}
"""Error kinds of a reply and the exception each becomes for the asker: after the samples of a
flow with no motion model (``no_model``, an ``ExtrapolationError``), otherwise outside what the
producer can answer (before its samples, beyond its prediction bound: ``extrapolation``), no
sample yet (``no_data``), the producer did not manage in time (``timeout``), a malformed
request (``invalid``)."""


def selector(key: str, timestamp_ns: int) -> str:
    """The selector asking ``key`` for its value at ``timestamp_ns``."""
    return f"{key}?{TIME_PARAMETER}={int(timestamp_ns)}"


def requested_time(parameters: Any) -> int | None:
    """The time a query asks for (its ``t`` parameter), None for a plain query; ``ValueError``
    for a ``t`` that is no timestamp (``core.measurements.check_timestamp``)."""
    text = parameters.get(TIME_PARAMETER)
    if text is None:
        return None
    if not (isinstance(text, str) and text.isascii() and text.isdigit() and len(text) <= 19):
        raise ValueError(f"{TIME_PARAMETER}: expected integer nanoseconds, got {str(text)[:40]!r}")
    return check_timestamp(TIME_PARAMETER, int(text))


def error_payload(error: Exception) -> bytes:
    """The error reply for ``error`` (one of :data:`ERRORS`' exceptions; anything else is
    reported as ``invalid``)."""
    kind = next((k for k, cls in ERRORS.items() if type(error) is cls), None)
    if kind is None:
        kind = next((k for k, cls in ERRORS.items() if isinstance(error, cls)), "invalid")
    return json.dumps({"error": kind, "message": str(error)[:500]}).encode()


def raise_error(payload: bytes, key: str) -> NoReturn:
    """Raise the typed exception an error reply from ``key`` names; a reply that is not one
    (zenoh's own, e.g. on a query's time-out) is :class:`NoDataError` quoting it."""
    try:
        reply = json.loads(payload[:4096])
        kind, message = reply["error"], str(reply["message"])
        error = ERRORS[kind]
    except (ValueError, KeyError, TypeError):
        raise NoDataError(f"{key}: no answer ({payload[:80]!r})") from None
    raise error(f"{key}: {message}")


def fetch_at(session: Any, key: str, timestamp_ns: int, timeout: float) -> bytes:
    """The payload ``key``'s producer answers for ``timestamp_ns``; raises the error it
    replies (:func:`raise_error`), or :class:`NoDataError` if nothing answers within
    ``timeout`` seconds. Blocks: never call it from a zenoh callback."""
    error: bytes | None = None
    for reply in session.get(selector(key, timestamp_ns), timeout=timeout):
        if reply.ok is not None:
            if not is_misaddressed(reply.ok):  # an answer put on another key: net.address
                return reply.ok.payload.to_bytes()
            continue
        error = reply.err.payload.to_bytes()
    if error is not None:
        raise_error(error, key)
    raise NoDataError(f"{key}: no producer answered for time {timestamp_ns} within {timeout} s")
