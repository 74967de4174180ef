"""A.R.T. DTrack2/DTRACK3 ASCII UDP output: encode and parse the lines ``fr``, ``ts``,
``6dcal``, ``6d`` and ``3d``.

Format (A.R.T. DTrackSDK ``src/DTrackParser.cpp`` and ``include/DTrackDataTypes.hpp``; Flystick
manual appendix B.2; summarised in ``../shared/reference/field-notes.md`` section 6): one
datagram per frame, one line per data type separated by CR/LF, items in ``[...]`` blocks::

    fr 21753
    ts 39596.024831
    6dcal 2
    6d 1 [0 1.000][326.848 -187.216 109.503 -160.4704 -3.6963 -7.0913][-0.940508 ... 0.990286]
    3d 1 [1 1.000][10.000 20.000 30.000]

* ``fr``: frame counter; ``ts``: seconds since 00:00 UTC (6 decimals; wraps at midnight);
  ``6dcal``: number of calibrated bodies (tracked or not);
* ``6d n [id qu][sx sy sz eta theta phi][b0 .. b8]``: the ``n`` *tracked* bodies (untracked
  ones are omitted), body ids from 0, position in millimetres, Euler angles in degrees (which
  ART recommends ignoring; the parser does), rotation matrix column-wise
  ``R = [[b0 b3 b6], [b1 b4 b7], [b2 b5 b8]]``;
* ``3d n [id qu][sx sy sz]``: single markers, ids from 1, millimetres.

Unknown line types are skipped ("could be valid in future DTracks", DTrackSDK). Anything else
that does not follow the format raises :class:`DTrackFormatError`, and only that.

This module is pure: units stay DTrack's (mm); the adapter converts.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

MAX_ITEMS = 10_000
"""Largest accepted number of bodies or markers in one line (a guard against bogus counts)."""

DAY_NS = 86_400 * 1_000_000_000

_BLOCK = re.compile(r"\[([^\[\]]*)\]")


class DTrackFormatError(ValueError):
    """A datagram does not follow the DTrack ASCII format; the message says where."""


@dataclass(frozen=True)
class Body6D:
    """One tracked body of a ``6d`` line: id (from 0), quality, position (mm), rotation."""

    id: int
    quality: float
    position_mm: np.ndarray
    rotation: np.ndarray
    """3x3 rotation matrix of the body in the tracker frame."""


@dataclass(frozen=True)
class Marker3D:
    """One single marker of a ``3d`` line: id (from 1), quality, position (mm)."""

    id: int
    quality: float
    position_mm: np.ndarray


@dataclass(frozen=True)
class DTrackFrame:
    """The content of one datagram; ``timestamp_s`` is ``None`` without a ``ts`` line."""

    frame: int
    timestamp_s: float | None = None
    calibrated_bodies: int | None = None
    bodies: tuple[Body6D, ...] = field(default_factory=tuple)
    markers: tuple[Marker3D, ...] = field(default_factory=tuple)


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


def _int(where: str, text: str, low: int = 0) -> int:
    try:
        value = int(text)
    except ValueError:
        raise DTrackFormatError(f"{where}: expected an integer, got {text!r}") from None
    if value < low:
        raise DTrackFormatError(f"{where}: must be >= {low}, got {value}")
    return value


def _floats(where: str, text: str, count: int) -> np.ndarray:
    parts = text.split()
    if len(parts) != count:
        raise DTrackFormatError(f"{where}: expected {count} numbers, got {len(parts)}")
    try:
        values = np.array([float(p) for p in parts])
    except ValueError:
        raise DTrackFormatError(f"{where}: not a number in {text!r}") from None
    if not np.isfinite(values).all():
        raise DTrackFormatError(f"{where}: NaN or infinity in {text!r}")
    return values


def _items(line_id: str, rest: str, blocks_per_item: int) -> list[list[str]]:
    """Split ``<n> [..][..] ...`` into ``n`` items of ``blocks_per_item`` blocks each."""
    start = rest.find("[")
    head, body = (rest, "") if start < 0 else (rest[:start], rest[start:])
    count = _int(f"{line_id}: count", head.strip())
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


def _id_quality(where: str, text: str, low: int) -> tuple[int, float]:
    parts = text.split()
    if len(parts) != 2:
        raise DTrackFormatError(f"{where}: expected [id quality], got [{text}]")
    quality = _floats(where, parts[1], 1)[0]
    return _int(f"{where} id", parts[0], low), float(quality)


def _rotation(where: str, values: np.ndarray) -> np.ndarray:
    rotation = values.reshape(3, 3).T  # column-wise: b0 b1 b2 is the first column
    if not math.isclose(float(np.linalg.det(rotation)), 1.0, abs_tol=1e-3) or not np.allclose(
        rotation.T @ rotation, np.eye(3), atol=1e-3
    ):
        raise DTrackFormatError(f"{where}: not a rotation matrix")
    return rotation


def _parse_6d(rest: str) -> tuple[Body6D, ...]:
    bodies = []
    for index, (head, pose, matrix) in enumerate(_items("6d", rest, 3)):
        where = f"6d body {index}"
        body_id, quality = _id_quality(where, head, 0)
        position_angles = _floats(f"{where} position", pose, 6)
        rotation = _rotation(f"{where} matrix", _floats(f"{where} matrix", matrix, 9))
        bodies.append(Body6D(body_id, quality, position_angles[:3], rotation))
    return tuple(bodies)


def _parse_3d(rest: str) -> tuple[Marker3D, ...]:
    markers = []
    for index, (head, position) in enumerate(_items("3d", rest, 2)):
        where = f"3d marker {index}"
        marker_id, quality = _id_quality(where, head, 1)
        markers.append(Marker3D(marker_id, quality, _floats(f"{where} position", position, 3)))
    return tuple(markers)


def parse_frame(datagram: bytes) -> DTrackFrame:
    """Parse one datagram; raises :class:`DTrackFormatError` if it is malformed."""
    try:
        text = datagram.decode("ascii")
    except UnicodeDecodeError:
        raise DTrackFormatError("datagram is not ASCII") from None
    lines = [line.strip() for line in re.split(r"[\r\n]+", text) if line.strip()]
    if not lines or not lines[0].startswith("fr "):
        raise DTrackFormatError("datagram does not start with an 'fr' line")
    values: dict[str, object] = {}
    for line in lines:
        line_id, _, rest = line.partition(" ")
        if line_id in values:
            raise DTrackFormatError(f"line {line_id!r} appears twice")
        if line_id == "fr":
            values[line_id] = _int("fr", rest.strip())
        elif line_id == "ts":
            stamp = _floats("ts", rest, 1)[0]
            if not 0.0 <= stamp <= 86400.0:
                raise DTrackFormatError(f"ts: {stamp} is not seconds since midnight")
            values[line_id] = float(stamp)
        elif line_id == "6dcal":
            values[line_id] = _int("6dcal", rest.strip())
        elif line_id == "6d":
            values[line_id] = _parse_6d(rest)
        elif line_id == "3d":
            values[line_id] = _parse_3d(rest)
    return DTrackFrame(
        frame=values["fr"],  # type: ignore[arg-type]
        timestamp_s=values.get("ts"),  # type: ignore[arg-type]
        calibrated_bodies=values.get("6dcal"),  # type: ignore[arg-type]
        bodies=values.get("6d", ()),  # type: ignore[arg-type]
        markers=values.get("3d", ()),  # type: ignore[arg-type]
    )
