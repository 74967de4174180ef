"""A.R.T. DTrack2/DTRACK3 ASCII UDP output: encode the lines ``fr``, ``ts``, ``6dcal``, ``6d``
and ``3d``; parse those and ``ts2``, ``6di``, ``6df``/``6df2`` and ``6dmt``/``6dmt2``.

Format (A.R.T. DTrackSDK ``src/DTrackParser.cpp``, ``src/DTrackParse.cpp`` and
``include/DTrackDataTypes.hpp``; Flystick manual appendix B.2; summarised in
``../shared/reference/field-notes.md`` section 6): one datagram per frame, one line per data
type separated by CR/LF, items in ``[...]`` blocks::

    fr 21753
    ts 39596.024831
    6dcal 2
    6d 1 [0 1.000][326.848 -187.216 109.503 -160.4704 -3.6963 -7.0913][-0.940508 ... 0.990286]
    3d 1 [1 1.000][10.000 20.000 30.000]

* ``fr``: frame counter; ``ts``: seconds since 00:00 UTC (6 decimals; wraps at midnight);
  ``ts2 <unix_sec> <usec> <latency_usec>`` (DTRACK3): the Unix time of the measurement and
  the controller's latency; ``6dcal``: number of calibrated bodies (tracked or not);
* ``6d n [id qu][sx sy sz eta theta phi][b0 .. b8]``: the ``n`` *tracked* bodies, body ids
  from 0, position in millimetres, Euler angles in degrees (which ART recommends ignoring; the
  parser does), rotation matrix column-wise ``R = [[b0 b3 b6], [b1 b4 b7], [b2 b5 b8]]``;
* ``6di n [id st er][sx sy sz][b0 .. b8]``: hybrid (optical-inertial) bodies, listed even when
  untracked; ``st`` 0..3 is none/inertial/optical/both, ``er`` the drift estimate (degrees);
* ``6df n [id qu bt][sx sy sz eta theta phi][b0 .. b8]`` and ``6df2 n_defined n [id qu nbt
  nct][sx sy sz][b0 .. b8][buttons joysticks]``: Flysticks, ids from 0 in order, every defined
  one listed (an untracked one with quality -1 and a zero matrix); buttons and joysticks are
  checked to be present but not returned;
* ``6dmt n [id qu bt][sx sy sz][b0 .. b8]`` and ``6dmt2 n_defined n [id qu nbt radius][sx sy
  sz][b0 .. b8][buttons][c00 c01 c02 c11 c12 c22]``: measurement tools (ids from 0 in order),
  ``6dmt2`` with the tip radius and the upper triangle of the position's covariance (mm^2);
* ``3d n [id qu][sx sy sz]``: single markers, ids from 1, millimetres.

Parsing follows the SDK's parser: a block holds *at least* the values a line type needs and
extra values are ignored (the SDK's ``string_get_block``: "ignore additional data inside the
block"), so the ``6d`` position block's angles are read as extra values; untracked items
(quality < 0, an all-zero rotation matrix, a ``6di`` status of 0) are left out of the result
rather than rejected; the datagram ends at its first NUL byte, as the SDK's C string does; and
lines of another type are skipped ("could be valid in future DTracks") and named in
:attr:`DTrackFrame.skipped_lines`, so the caller can say so. A known line that does not follow
its format fails the whole datagram, as the SDK's receive does: :class:`DTrackFormatError`,
naming the line and the item, is the only exception this module raises for any input.

This module is pure: units stay DTrack's (mm); the adapter converts.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

MAX_ITEMS = 10_000
"""Largest accepted number of items in one line (a guard against bogus counts)."""

DAY_NS = 86_400 * 1_000_000_000

_BLOCK = re.compile(r"\[([^\[\]]*)\]")

UNSUPPORTED_LINES = frozenset({"6dcov", "6dj", "6dmtr", "gl", "glcal", "st"})
"""Line types DTrack sends that this module skips (reported in
:attr:`DTrackFrame.skipped_lines` like unknown ones): covariances, ART-Human joints,
measurement-tool references, Fingertracking, system status."""


class DTrackFormatError(ValueError):
    """A datagram does not follow the DTrack ASCII format; the message says where."""


@dataclass(frozen=True)
class Body6D:
    """One tracked 6DOF item: a ``6d`` or ``6di`` body, a Flystick or a measurement tool."""

    id: int
    quality: float | None
    """DTrack's quality (>= 0 for a tracked item); ``None`` for a ``6di`` body, which reports
    a tracking status instead."""
    position_mm: np.ndarray
    rotation: np.ndarray
    """3x3 rotation matrix of the item in the tracker frame."""
    position_covariance_mm2: np.ndarray | None = None
    """``6dmt2`` only: DTrack's 3x3 covariance of the position (mm^2)."""


@dataclass(frozen=True)
class Marker3D:
    """One single marker of a ``3d`` line: id (from 1), quality, position (mm)."""

    id: int
    quality: float
    position_mm: np.ndarray


@dataclass(frozen=True)
class UnixTime:
    """A ``ts2`` line: the measurement's Unix time and the controller's latency (ns)."""

    unix_ns: int
    latency_ns: int


@dataclass(frozen=True)
class DTrackFrame:
    """The tracked content of one datagram; ``timestamp_s`` is ``None`` without a ``ts``
    line, ``unix_time`` without a ``ts2`` line."""

    frame: int
    timestamp_s: float | None = None
    calibrated_bodies: int | None = None
    bodies: tuple[Body6D, ...] = field(default_factory=tuple)
    markers: tuple[Marker3D, ...] = field(default_factory=tuple)
    hybrid_bodies: tuple[Body6D, ...] = field(default_factory=tuple)
    flysticks: tuple[Body6D, ...] = field(default_factory=tuple)
    tools: tuple[Body6D, ...] = field(default_factory=tuple)
    unix_time: UnixTime | None = None
    skipped_lines: tuple[str, ...] = ()
    """Identifiers of the lines skipped (:data:`UNSUPPORTED_LINES` and unknown ones), each once."""


def seconds_of_day(timestamp_ns: int) -> float:
    """DTrack's ``ts`` of a Unix time: seconds since 00:00 UTC, truncated to microseconds."""
    return (timestamp_ns % DAY_NS) // 1000 / 1e6


def timestamp_from_ts(seconds: float, host_ns: int) -> int:
    """Unix time (ns) of DTrack's ``ts`` ``seconds``, placed on the UTC day of ``host_ns`` and
    moved by a day if that puts it more than 12 hours away (``ts`` wraps at midnight; VRPN's
    ``vrpn_Tracker_DTrack.C`` does the same)."""
    stamp = host_ns - host_ns % DAY_NS + round(seconds * 1e6) * 1000
    if stamp - host_ns > DAY_NS // 2:
        stamp -= DAY_NS
    elif host_ns - stamp > DAY_NS // 2:
        stamp += DAY_NS
    return stamp


def _euler_deg(rotation: np.ndarray) -> np.ndarray:
    """DTrack's angles (eta, theta, phi) of ``R = Rx(phi) Ry(theta) Rz(eta)``, as in the
    SDK's example line (``tests/unit/test_dtrack_format.py`` checks it)."""
    return Rotation.from_matrix(rotation).as_euler("zyx", degrees=True)


def encode_frame(frame: DTrackFrame) -> bytes:
    """One datagram: ``fr``, then ``ts``/``6dcal`` if set, ``6d`` and ``3d`` (both always
    present, possibly with count 0), CR/LF separated, with DTrack's number formats (3 decimals
    for millimetres and quality, 4 for angles, 6 for matrix entries and the timestamp)."""
    lines = [f"fr {frame.frame}"]
    if frame.timestamp_s is not None:
        lines.append(f"ts {frame.timestamp_s:.6f}")
    if frame.calibrated_bodies is not None:
        lines.append(f"6dcal {frame.calibrated_bodies}")
    items = []
    for body in frame.bodies:
        position = " ".join(f"{v:.3f}" for v in body.position_mm)
        angles = " ".join(f"{v:.4f}" for v in _euler_deg(body.rotation))
        matrix = " ".join(f"{v:.6f}" for v in np.asarray(body.rotation).T.ravel())
        items.append(f"[{body.id} {body.quality:.3f}][{position} {angles}][{matrix}]")
    lines.append(" ".join([f"6d {len(frame.bodies)}", *items]))
    items = [
        f"[{m.id} {m.quality:.3f}][{' '.join(f'{v:.3f}' for v in m.position_mm)}]"
        for m in frame.markers
    ]
    lines.append(" ".join([f"3d {len(frame.markers)}", *items]))
    return ("\r\n".join(lines) + "\r\n").encode("ascii")


def _fields(where: str, text: str, count: int) -> list[str]:
    """The first ``count`` values of a block; extra values are ignored, as the SDK's
    ``string_get_block`` does, too few are an error."""
    parts = text.split()
    if len(parts) < count:
        raise DTrackFormatError(f"{where}: expected {count} values, got {len(parts)}")
    return parts[:count]


def _int(where: str, text: str, low: int = 0) -> int:
    try:
        value = int(text)
    except ValueError:
        raise DTrackFormatError(f"{where}: expected an integer, got {text!r}") from None
    if value < low:
        raise DTrackFormatError(f"{where}: must be >= {low}, got {value}")
    return value


def _float(where: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise DTrackFormatError(f"{where}: not a number: {text!r}") from None
    if not math.isfinite(value):
        raise DTrackFormatError(f"{where}: NaN or infinity: {text!r}")
    return value


def _floats(where: str, text: str, count: int) -> np.ndarray:
    """The first ``count`` values of a block as numbers (:func:`_fields`)."""
    return np.array([_float(where, part) for part in _fields(where, text, count)])


def _items(line_id: str, rest: str, counts: int, blocks_per_item: int) -> list[list[str]]:
    """Split ``<counts numbers> [..][..] ...`` into items of ``blocks_per_item`` blocks; the
    last number is the item count (``6df2``/``6dmt2`` give the defined ones first)."""
    start = rest.find("[")
    head, body = (rest, "") if start < 0 else (rest[:start], rest[start:])
    numbers = head.split()
    if len(numbers) != counts:
        raise DTrackFormatError(f"{line_id}: expected {counts} count(s), got {head.strip()!r}")
    for number in numbers[:-1]:
        _int(f"{line_id}: count", number)
    count = _int(f"{line_id}: count", numbers[-1])
    if count > MAX_ITEMS:
        raise DTrackFormatError(f"{line_id}: count {count} exceeds {MAX_ITEMS}")
    blocks = _BLOCK.findall(body)
    if _BLOCK.sub("", body).strip():
        raise DTrackFormatError(f"{line_id}: text outside [...] blocks")
    if len(blocks) != count * blocks_per_item:
        raise DTrackFormatError(
            f"{line_id}: count says {count} items of {blocks_per_item} blocks, "
            f"got {len(blocks)} blocks"
        )
    return [blocks[i : i + blocks_per_item] for i in range(0, len(blocks), blocks_per_item)]


def _rotation(where: str, values: np.ndarray) -> np.ndarray:
    rotation = values.reshape(3, 3).T  # column-wise: b0 b1 b2 is the first column
    if not math.isclose(float(np.linalg.det(rotation)), 1.0, abs_tol=1e-3) or not np.allclose(
        rotation.T @ rotation, np.eye(3), atol=1e-3
    ):
        raise DTrackFormatError(f"{where}: not a rotation matrix")
    return rotation


def _pose(
    where: str, tracked: bool, position: str, matrix: str
) -> tuple[np.ndarray, np.ndarray] | None:
    """Position (mm) and rotation of an item, ``None`` if it is untracked: not ``tracked``
    by its quality or status, or with DTrack's all-zero matrix of an untracked Flystick. The
    blocks are read either way, as the SDK does, so a malformed one still fails."""
    position_mm = _floats(f"{where} position", position, 3)
    values = _floats(f"{where} matrix", matrix, 9)
    if not tracked or not values.any():
        return None
    return position_mm, _rotation(f"{where} matrix", values)


def _head(where: str, text: str, width: int, low: int = 0) -> tuple[int, float, list[str]]:
    """``[id qu ...]``: the id, the quality and all ``width`` values."""
    values = _fields(where, text, width)
    return _int(f"{where} id", values[0], low), _float(f"{where} quality", values[1]), values


def _check_index(where: str, item_id: int, index: int) -> None:
    """Flysticks and measurement tools are listed in id order; the SDK fails otherwise."""
    if item_id != index:
        raise DTrackFormatError(f"{where}: id {item_id} where {index} is expected")


def _check_buttons(where: str, text: str, buttons: str, joysticks: str = "0") -> None:
    """The buttons block holds ``ceil(nbt / 32)`` integers (and the joysticks' values)."""
    needed = -(-_int(f"{where} buttons", buttons) // 32) + _int(f"{where} joysticks", joysticks)
    _fields(f"{where} buttons", text, needed)


def _parse_poses(line_id: str, label: str, rest: str) -> tuple[Body6D, ...]:
    """``6d n [id qu]``, or ``6df``/``6dmt`` ``n [id qu bt]`` (listed in id order), each item
    then ``[sx sy sz ...][b0 .. b8]``."""
    with_buttons = line_id != "6d"
    items = []
    for index, (head, position, matrix) in enumerate(_items(line_id, rest, 1, 3)):
        where = f"{line_id} {label} {index}"
        item_id, quality, values = _head(where, head, 3 if with_buttons else 2)
        if with_buttons:
            _check_index(where, item_id, index)
            _int(f"{where} buttons", values[2])
        if pose := _pose(where, quality >= 0, position, matrix):
            items.append(Body6D(item_id, quality, *pose))
    return tuple(items)


def _parse_6di(rest: str) -> tuple[Body6D, ...]:
    bodies = []
    for index, (head, position, matrix) in enumerate(_items("6di", rest, 1, 3)):
        where = f"6di body {index}"
        values = _fields(where, head, 3)
        body_id = _int(f"{where} id", values[0])
        status = _int(f"{where} status", values[1])
        _float(f"{where} drift", values[2])
        if pose := _pose(where, status > 0, position, matrix):
            bodies.append(Body6D(body_id, None, *pose))
    return tuple(bodies)


def _parse_6df2(rest: str) -> tuple[Body6D, ...]:
    flysticks = []
    for index, (head, position, matrix, buttons) in enumerate(_items("6df2", rest, 2, 4)):
        where = f"6df2 Flystick {index}"
        flystick_id, quality, values = _head(where, head, 4)
        _check_index(where, flystick_id, index)
        _check_buttons(where, buttons, values[2], values[3])
        if pose := _pose(where, quality >= 0, position, matrix):
            flysticks.append(Body6D(flystick_id, quality, *pose))
    return tuple(flysticks)


def _covariance(where: str, text: str) -> np.ndarray:
    """The 3x3 covariance of ``6dmt2``'s upper triangle ``c00 c01 c02 c11 c12 c22``."""
    c00, c01, c02, c11, c12, c22 = _floats(where, text, 6)
    return np.array([[c00, c01, c02], [c01, c11, c12], [c02, c12, c22]])


def _parse_6dmt2(rest: str) -> tuple[Body6D, ...]:
    tools = []
    for index, blocks in enumerate(_items("6dmt2", rest, 2, 5)):
        head, position, matrix, buttons, covariance = blocks
        where = f"6dmt2 tool {index}"
        tool_id, quality, values = _head(where, head, 4)
        _check_index(where, tool_id, index)
        _float(f"{where} tip radius", values[3])
        _check_buttons(where, buttons, values[2])
        cov = _covariance(f"{where} covariance", covariance)
        if pose := _pose(where, quality >= 0, position, matrix):
            tools.append(Body6D(tool_id, quality, *pose, position_covariance_mm2=cov))
    return tuple(tools)


def _parse_3d(rest: str) -> tuple[Marker3D, ...]:
    markers = []
    for index, (head, position) in enumerate(_items("3d", rest, 1, 2)):
        where = f"3d marker {index}"
        marker_id, quality, _ = _head(where, head, 2, low=1)
        position_mm = _floats(f"{where} position", position, 3)
        if quality >= 0:
            markers.append(Marker3D(marker_id, quality, position_mm))
    return tuple(markers)


def _parse_ts(rest: str) -> float:
    stamp = float(_floats("ts", rest, 1)[0])
    if not 0.0 <= stamp <= 86400.0:
        raise DTrackFormatError(f"ts: {stamp} is not seconds since midnight")
    return stamp


def _parse_ts2(rest: str) -> UnixTime:
    seconds, micros, latency = (_int("ts2", value) for value in _fields("ts2", rest, 3))
    if micros >= 1_000_000:
        raise DTrackFormatError(f"ts2: {micros} microseconds is not below one second")
    return UnixTime(seconds * 1_000_000_000 + micros * 1000, latency * 1000)


_LINES: dict[str, tuple[str, Callable[[str], Any]]] = {
    "fr": ("frame", lambda rest: _int("fr", rest.strip())),
    "ts": ("timestamp_s", _parse_ts),
    "ts2": ("unix_time", _parse_ts2),
    "6dcal": ("calibrated_bodies", lambda rest: _int("6dcal", rest.strip())),
    "6d": ("bodies", partial(_parse_poses, "6d", "body")),
    "6di": ("hybrid_bodies", _parse_6di),
    "6df": ("flysticks", partial(_parse_poses, "6df", "Flystick")),
    "6df2": ("flysticks", _parse_6df2),
    "6dmt": ("tools", partial(_parse_poses, "6dmt", "tool")),
    "6dmt2": ("tools", _parse_6dmt2),
    "3d": ("markers", _parse_3d),
}
"""Each parsed line type: the :class:`DTrackFrame` field it fills and its parser."""


def _lines(datagram: bytes) -> list[str]:
    """The datagram's non-empty lines, up to its first NUL (the SDK reads a C string)."""
    try:
        text = datagram.split(b"\0", 1)[0].decode("ascii")
    except UnicodeDecodeError:
        raise DTrackFormatError("datagram is not ASCII") from None
    return [line.strip() for line in re.split(r"[\r\n]+", text) if line.strip()]


def parse_frame(datagram: bytes) -> DTrackFrame:
    """Parse one datagram as the SDK does (see the module docstring); raises
    :class:`DTrackFormatError` if a line it knows is malformed."""
    lines = _lines(datagram)
    if not lines or not lines[0].startswith("fr "):
        raise DTrackFormatError("datagram does not start with an 'fr' line")
    values: dict[str, Any] = {}
    given_by: dict[str, str] = {}
    skipped: dict[str, None] = {}
    for line in lines:
        line_id, _, rest = line.partition(" ")
        if line_id not in _LINES:
            skipped[line_id] = None
            continue
        name, parse = _LINES[line_id]
        if name in given_by:
            first = given_by[name]
            also = "" if first == line_id else f" (as {first!r})"
            raise DTrackFormatError(f"line {line_id!r} appears twice{also}")
        given_by[name] = line_id
        values[name] = parse(rest)
    return DTrackFrame(**values, skipped_lines=tuple(skipped))
