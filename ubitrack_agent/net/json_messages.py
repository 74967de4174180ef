"""JSON messages from the network, read totally: bounded size, bounded nesting, one object.

Every JSON message the middleware receives (host requests and reports, calibration progress,
worker control commands, component specifications) is first read by :func:`load_object`,
which returns a ``dict`` or raises :class:`MessageError` and nothing else, whatever the bytes
hold: not UTF-8, not JSON, larger than the caller's bound, nested deeper than
:data:`MAX_DEPTH`, or not an object. The depth bound keeps every later step (copying,
comparing, re-encoding the message) far from Python's recursion limit. Fields are then checked
by the message's own parser with :func:`field`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

MAX_DEPTH = 32
"""Deepest nesting of objects and arrays accepted (the top-level object is depth 1); a
specification nests four deep."""


class MessageError(ValueError):
    """A message that cannot be read; ``error`` names the kind (``malformed_request``,
    ``oversized_request``) and ``reason`` says why."""

    def __init__(self, error: str, reason: str) -> None:
        super().__init__(f"{error}: {reason}")
        self.error = error
        self.reason = reason


def load_object(payload: bytes | None, max_bytes: int) -> dict[str, Any]:
    """The JSON object in ``payload`` (see the module docstring)."""
    if payload is None or not payload:
        raise MessageError("malformed_request", "empty payload: expected a JSON object")
    if len(payload) > max_bytes:
        raise MessageError("oversized_request", f"{len(payload)} bytes, at most {max_bytes}")
    try:
        data = json.loads(payload.decode("utf-8"))
    except UnicodeDecodeError:
        raise MessageError("malformed_request", "not UTF-8") from None
    except json.JSONDecodeError as exc:
        raise MessageError("malformed_request", f"not JSON ({exc})") from None
    except RecursionError:
        raise MessageError("malformed_request", "nested too deeply") from None
    except ValueError as exc:  # an integer literal of more digits than Python converts
        raise MessageError("malformed_request", f"not JSON ({exc})") from None
    if not isinstance(data, dict):
        raise MessageError("malformed_request", "expected a JSON object")
    if _deeper_than(data, MAX_DEPTH):
        raise MessageError("malformed_request", f"nested deeper than {MAX_DEPTH}")
    return data


def _deeper_than(data: Any, limit: int) -> bool:
    """Whether ``data`` nests objects and arrays more than ``limit`` deep (without recursion)."""
    stack = [(data, 1)]
    while stack:
        value, depth = stack.pop()
        if isinstance(value, dict):
            value = value.values()
        elif not isinstance(value, list):
            continue
        if depth > limit:
            return True
        stack.extend((child, depth + 1) for child in value)
    return False


def field(data: Mapping[str, Any], name: str, kind: type, optional: bool = False) -> Any:
    """``data[name]`` if it is exactly of ``kind`` (``bool`` is no ``int``; a ``float`` must be
    finite, and an ``int`` is accepted for it), or ``None`` when ``optional`` and absent or
    null; else :class:`MessageError`."""
    value = data.get(name)
    if value is None and optional:
        return None
    if kind is float and type(value) is int:
        try:
            value = float(value)
        except OverflowError:  # an integer literal beyond any float
            raise MessageError("malformed_request", f"{name}: expected float") from None
    if type(value) is not kind or (kind is float and not math.isfinite(value)):
        raise MessageError("malformed_request", f"{name}: expected {kind.__name__}")
    return value
