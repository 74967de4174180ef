"""OptiTrack NatNet 3.0-4.x: parse and build the UDP packets of Motive's stream.

Layouts follow the NatNet SDK's samples (``Samples/PythonClient/NatNetClient.py`` and
``Samples/PacketClient/PacketClient.cpp`` of SDK 3.1; the SDK 4.x Python sample client) and
the PyPI client ``natnet`` 0.3 (``natnet/data_frame.py``, ``data_descriptions.py``); where
they disagree the C++ sample wins (``docs/natnet.md`` lists the differences). Every packet
is ``uint16 message id, uint16 payload size, payload``, little-endian:

* ``NAT_CONNECT`` (client -> server): ``sSender`` (256-byte name, app version, NatNet version)
  then ``sConnectionOptions`` (``bool subscribedDataOnly``, ``uint8 BitstreamVersion[4]``),
  269 bytes, as libNatNet 4.x sends; the SDK's Python sample pads it to 270 plus a NUL.
* ``NAT_SERVERINFO``: ``sSender`` (264 bytes) and, from NatNet 3.0, ``uint64`` high-resolution
  clock frequency, ``uint16`` data port, ``bool`` multicast, ``uint8[4]`` multicast group.
* ``NAT_MODELDEF``: ``int32`` count, then per dataset ``int32`` type (0 marker set, 1 rigid
  body, 2 skeleton, 3 force plate, 4 device, 5 camera, 6 asset) and, from 4.1, its ``int32``
  byte size. A rigid body: name, ``int32`` id, ``int32`` parent id, offset ``3 float``,
  (4.2+) rotation ``4 float``, ``int32 n``, ``n`` marker offsets, ``n`` active labels,
  (4.0+) ``n`` marker names.
* ``NAT_FRAMEOFDATA``: ``int32`` frame number; then sections, each ``int32`` count and (4.1+)
  ``int32`` byte size: marker sets, legacy markers, rigid bodies (``int32`` id, position
  ``3 float`` metres, rotation ``4 float`` x, y, z, w, ``float`` mean marker error metres,
  ``int16`` params, bit 0 tracking valid), skeletons, (4.1+) assets, labeled markers, force
  plates, devices; then timecode ``2 uint32``, timestamp ``double`` (seconds of Motive's
  clock), mid-exposure, data-received and transmit timestamps ``3 uint64`` (ticks of the
  server's high-resolution clock), (4.1+) precision timestamp ``2 uint32``, ``int16`` params
  (bit 0 recording, bit 1 tracked models changed) and an optional ``int32`` end-of-data tag.

Parsing is total: any input either parses or raises :class:`NatNetFormatError` naming the
field; counts are checked against the bytes left before anything is allocated, so a hostile
count cannot make work. O(n) in the packet's bytes. This module is pure (no sockets, no
clock); units stay NatNet's (metres).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from typing import NamedTuple

NAT_CONNECT = 0
NAT_SERVERINFO = 1
NAT_REQUEST = 2
NAT_RESPONSE = 3
NAT_REQUEST_MODELDEF = 4
NAT_MODELDEF = 5
NAT_REQUEST_FRAMEOFDATA = 6
NAT_FRAMEOFDATA = 7
NAT_MESSAGESTRING = 8
NAT_DISCONNECT = 9
NAT_KEEPALIVE = 10
NAT_UNRECOGNIZED_REQUEST = 100

NAME_FIELD = 256
"""Bytes of ``sSender``'s name field."""

SENDER_BYTES = NAME_FIELD + 8
CONNECT_BYTES = SENDER_BYTES + 5
SERVER_INFO_BYTES = SENDER_BYTES + 15
"""``sSender_Server``: ``sSender`` + clock frequency, data port, multicast flag, group."""

RIGID_BODY_BYTES = 38
"""A rigid body in a frame (3.0+): id, position, rotation, mean error, params."""

LABELED_MARKER_BYTES = 26
ASSET_MARKER_BYTES = 26


class NatNetFormatError(ValueError):
    """A packet does not follow the NatNet layout; the message says where."""


class NatNetVersion(NamedTuple):
    """A NatNet (bitstream) version, ``major.minor.build.revision``."""

    major: int
    minor: int
    build: int = 0
    revision: int = 0

    def at_least(self, major: int, minor: int = 0) -> bool:
        return (self.major, self.minor) >= (major, minor)

    def __str__(self) -> str:
        return ".".join(map(str, self))


def supported(version: NatNetVersion) -> bool:
    """Whether this module parses ``version``: 3.0 to 4.x (2.x streams put marker lists in
    rigid bodies, 5.x is not yet defined)."""
    return version.major in (3, 4)


@dataclass(frozen=True)
class ServerInfo:
    """``NAT_SERVERINFO``: the server's name and versions and, from NatNet 3.0, its clock
    frequency and connection settings (``None`` from an older server)."""

    application: str
    application_version: NatNetVersion
    natnet_version: NatNetVersion
    clock_frequency_hz: int | None = None
    data_port: int | None = None
    multicast: bool | None = None
    multicast_group: str | None = None


@dataclass(frozen=True)
class RigidBodyDescription:
    """A rigid body of ``NAT_MODELDEF``: Motive's name and streaming id."""

    name: str
    id: int
    parent_id: int = -1
    offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    marker_offsets_m: tuple[tuple[float, float, float], ...] = ()


@dataclass(frozen=True)
class ModelDefinitions:
    """The rigid bodies of ``NAT_MODELDEF`` and how many datasets of other kinds it held."""

    rigid_bodies: tuple[RigidBodyDescription, ...] = ()
    other_datasets: int = 0


@dataclass(frozen=True)
class RigidBody:
    """One rigid body of a frame: streaming id, pose (metres; quaternion x, y, z, w), Motive's
    mean marker error (metres) and whether it was tracked in this frame."""

    id: int
    position_m: tuple[float, float, float]
    rotation: tuple[float, float, float, float]
    mean_error_m: float = 0.0
    tracking_valid: bool = True


@dataclass(frozen=True)
class Frame:
    """The parts of ``NAT_FRAMEOFDATA`` the adapter uses (other sections are skipped)."""

    number: int
    rigid_bodies: tuple[RigidBody, ...] = ()
    timestamp_s: float = 0.0
    """Motive's software clock (seconds since it started)."""
    mid_exposure_ticks: int = 0
    data_received_ticks: int = 0
    transmit_ticks: int = 0
    """High-resolution clock ticks of the server (frequency in :class:`ServerInfo`)."""
    precision_seconds: int = 0
    precision_fraction: int = 0
    """NatNet 4.1+: the optional precision (PTP) timestamp; 0 when absent."""
    recording: bool = False
    models_changed: bool = False
    skipped: dict[str, int] = field(default_factory=dict)
    """Items of the other sections, by section name (only the non-empty ones)."""


class _Reader:
    """Bounds-checked little-endian reads from a payload."""

    def __init__(self, data: bytes | memoryview, where: str) -> None:
        self.data = memoryview(data)
        self.offset = 0
        self.where = where

    def left(self) -> int:
        return len(self.data) - self.offset

    def fail(self, what: str) -> NatNetFormatError:
        return NatNetFormatError(f"{self.where} at byte {self.offset}: {what}")

    def unpack(self, layout: struct.Struct, what: str) -> tuple:
        if self.left() < layout.size:
            raise self.fail(f"{what}: needs {layout.size} bytes, {self.left()} left")
        values = layout.unpack_from(self.data, self.offset)
        self.offset += layout.size
        return values

    def int32(self, what: str) -> int:
        return self.unpack(_I32, what)[0]

    def count(self, what: str, item_bytes: int) -> int:
        """A non-negative ``int32`` count of items of at least ``item_bytes`` bytes each,
        checked against the bytes left (a hostile count makes no work)."""
        value = self.int32(what)
        if value < 0 or value * item_bytes > self.left():
            raise self.fail(f"{what} {value} does not fit the {self.left()} bytes left")
        return value

    def skip(self, size: int, what: str) -> None:
        if size < 0 or size > self.left():
            raise self.fail(f"{what}: {size} bytes do not fit the {self.left()} left")
        self.offset += size

    def floats(self, count: int, what: str) -> tuple[float, ...]:
        values = self.unpack(_FLOATS[count], what)
        if not all(math.isfinite(v) for v in values):
            raise self.fail(f"{what}: NaN or infinity")
        return values

    def string(self, what: str, limit: int | None = None) -> str:
        """A NUL-terminated UTF-8 string (within ``limit`` bytes if given)."""
        end = len(self.data) if limit is None else min(len(self.data), self.offset + limit)
        raw = bytes(self.data[self.offset : end])
        text, nul, _ = raw.partition(b"\0")
        if not nul:
            raise self.fail(f"{what}: no terminating NUL")
        try:
            decoded = text.decode("utf-8")
        except UnicodeDecodeError:
            raise self.fail(f"{what}: not UTF-8") from None
        self.offset += len(text) + 1
        return decoded


_I32 = struct.Struct("<i")
_HEADER = struct.Struct("<HH")
_FLOATS = {n: struct.Struct(f"<{n}f") for n in (3, 4)}
_BODY = struct.Struct("<i3f4ffh")
_SUFFIX = struct.Struct("<IIdQQQ")
_PRECISION = struct.Struct("<II")
_PARAMS = struct.Struct("<h")
_SERVER_TAIL = struct.Struct("<QH?4B")
_VERSION = struct.Struct("<4B")


def split_packet(data: bytes) -> tuple[int, memoryview]:
    """The message id and payload of one datagram; the header's size must match the
    datagram's (``NatNetFormatError`` otherwise)."""
    if len(data) < _HEADER.size:
        raise NatNetFormatError(f"packet of {len(data)} bytes has no 4-byte header")
    message_id, size = _HEADER.unpack_from(data)
    if size != len(data) - _HEADER.size:
        raise NatNetFormatError(
            f"message {message_id}: header says {size} payload bytes, got {len(data) - 4}"
        )
    return message_id, memoryview(data)[_HEADER.size :]


def packet(message_id: int, payload: bytes = b"") -> bytes:
    """One datagram: header and payload (``ValueError`` if it exceeds the 16-bit size)."""
    if len(payload) > 0xFFFF:
        raise ValueError(f"payload of {len(payload)} bytes does not fit NatNet's 16-bit size")
    return _HEADER.pack(message_id, len(payload)) + payload


def _name_field(name: str) -> bytes:
    encoded = name.encode("utf-8")[: NAME_FIELD - 1]
    return encoded + b"\0" * (NAME_FIELD - len(encoded))


def build_connect(name: str, requested: NatNetVersion | None = None) -> bytes:
    """``NAT_CONNECT`` as libNatNet 4.x sends it: ``sSender`` + ``sConnectionOptions``;
    ``requested`` is the bitstream version asked for (``None``: the server's)."""
    own = _VERSION.pack(4, 0, 0, 0)
    wanted = _VERSION.pack(*(requested or (0, 0, 0, 0)))
    return packet(NAT_CONNECT, _name_field(name) + own + own + b"\0" + wanted)


def parse_connect(payload: bytes | memoryview) -> NatNetVersion | None:
    """The bitstream version a ``NAT_CONNECT`` asks for, ``None`` if it asks for none: any
    payload is a valid connect (the SDK's Python sample sends 270 bytes, older clients
    ``"Ping"``), only a full ``sConnectionOptions`` (bytes 265-268) carries a version."""
    if len(payload) < CONNECT_BYTES:
        return None
    version = NatNetVersion(*_VERSION.unpack_from(payload, SENDER_BYTES + 1))
    return None if version == (0, 0, 0, 0) else version


def build_request(message_id: int, text: str = "") -> bytes:
    """A request without payload (``NAT_REQUEST_MODELDEF``, ``NAT_KEEPALIVE``), or a
    ``NAT_REQUEST`` command string, NUL-terminated."""
    return packet(message_id, text.encode("utf-8") + b"\0" if text else b"")


def build_server_info(info: ServerInfo) -> bytes:
    payload = (
        _name_field(info.application)
        + _VERSION.pack(*info.application_version)
        + _VERSION.pack(*info.natnet_version)
    )
    if info.clock_frequency_hz is not None:
        group = [int(part) for part in (info.multicast_group or "0.0.0.0").split(".")]
        payload += _SERVER_TAIL.pack(
            info.clock_frequency_hz, info.data_port or 0, bool(info.multicast), *group
        )
    return packet(NAT_SERVERINFO, payload)


def parse_server_info(payload: bytes | memoryview) -> ServerInfo:
    """``NAT_SERVERINFO``: ``sSender``, and ``sSender_Server``'s tail when present."""
    read = _Reader(payload, "server info")
    application = read.string("application name", NAME_FIELD)
    read.offset = NAME_FIELD
    application_version = NatNetVersion(*read.unpack(_VERSION, "application version"))
    natnet_version = NatNetVersion(*read.unpack(_VERSION, "NatNet version"))
    if read.left() < _SERVER_TAIL.size:
        return ServerInfo(application, application_version, natnet_version)
    frequency, port, multicast, *group = read.unpack(_SERVER_TAIL, "connection info")
    return ServerInfo(
        application,
        application_version,
        natnet_version,
        frequency,
        port,
        multicast,
        ".".join(map(str, group)),
    )


def _check_version(version: NatNetVersion) -> None:
    if not supported(version):
        raise NatNetFormatError(f"NatNet {version} is not supported (3.0 to 4.x are)")


def _sized(version: NatNetVersion) -> bool:
    """Whether sections and datasets carry their byte size (NatNet 4.1 and later)."""
    return version.at_least(4, 1)


# ---------------------------------------------------------------- model definitions


def _rigid_body_description(read: _Reader, version: NatNetVersion) -> RigidBodyDescription:
    name = read.string("rigid body name")
    body_id = read.int32("rigid body id")
    parent_id = read.int32("rigid body parent id")
    offset = read.floats(3, "rigid body offset")
    if version.at_least(4, 2):
        read.floats(4, "rigid body rotation")
    markers = read.count("rigid body marker count", 16)
    offsets = tuple(read.floats(3, "marker offset") for _ in range(markers))
    read.skip(4 * markers, "marker active labels")
    if version.at_least(4, 0):
        for _ in range(markers):
            read.string("marker name")
    return RigidBodyDescription(name, body_id, parent_id, offset, offsets)  # type: ignore[arg-type]


def _skip_marker_set_description(read: _Reader, version: NatNetVersion) -> None:
    read.string("marker set name")
    for _ in range(read.count("marker set marker count", 1)):
        read.string("marker name")


def _skip_skeleton_description(read: _Reader, version: NatNetVersion) -> None:
    read.string("skeleton name")
    read.int32("skeleton id")
    for _ in range(read.count("skeleton bone count", 1)):
        _rigid_body_description(read, version)


def _skip_force_plate_description(read: _Reader, version: NatNetVersion) -> None:
    read.int32("force plate id")
    read.string("force plate serial")
    read.skip(4 * (2 + 3 + 144 + 12) + 8, "force plate geometry")
    for _ in range(read.count("force plate channel count", 1)):
        read.string("force plate channel name")


def _skip_device_description(read: _Reader, version: NatNetVersion) -> None:
    read.int32("device id")
    read.string("device name")
    read.string("device serial")
    read.skip(8, "device type")
    for _ in range(read.count("device channel count", 1)):
        read.string("device channel name")


def _skip_camera_description(read: _Reader, version: NatNetVersion) -> None:
    read.string("camera name")
    read.skip(28, "camera pose")


_SKIP_DESCRIPTION = {
    0: _skip_marker_set_description,
    2: _skip_skeleton_description,
    3: _skip_force_plate_description,
    4: _skip_device_description,
    5: _skip_camera_description,
}
"""Dataset types a pre-4.1 description must be read through to reach the next one."""


def parse_model_definitions(
    payload: bytes | memoryview, version: NatNetVersion
) -> ModelDefinitions:
    """``NAT_MODELDEF`` at ``version``: the rigid bodies, other datasets skipped (by their
    size from 4.1, else by reading them; an unknown type before 4.1 cannot be skipped)."""
    _check_version(version)
    read = _Reader(payload, f"model definitions {version}")
    bodies, others = [], 0
    for _ in range(read.count("dataset count", 4)):
        kind = read.int32("dataset type")
        size = read.count("dataset size", 1) if _sized(version) else None
        start = read.offset
        if kind == 1:
            bodies.append(_rigid_body_description(read, version))
        elif size is not None:
            read.skip(size, f"dataset of type {kind}")
            others += 1
        elif kind in _SKIP_DESCRIPTION:
            _SKIP_DESCRIPTION[kind](read, version)
            others += 1
        else:
            raise read.fail(f"unknown dataset type {kind}")
        if size is not None and read.offset - start != size:
            raise read.fail(f"dataset of type {kind} is {read.offset - start} bytes, not {size}")
    if read.left():
        raise read.fail(f"{read.left()} bytes after the last dataset")
    return ModelDefinitions(tuple(bodies), others)


def build_model_definitions(
    bodies: list[RigidBodyDescription] | tuple[RigidBodyDescription, ...],
    version: NatNetVersion,
) -> bytes:
    """``NAT_MODELDEF`` listing ``bodies`` (their marker offsets; labels 0, names
    ``Marker<n>``) at ``version``."""
    _check_version(version)
    datasets = b""
    for body in bodies:
        data = body.name.encode("utf-8") + b"\0"
        data += struct.pack("<ii3f", body.id, body.parent_id, *body.offset_m)
        if version.at_least(4, 2):
            data += struct.pack("<4f", 0.0, 0.0, 0.0, 1.0)
        data += _I32.pack(len(body.marker_offsets_m))
        data += b"".join(struct.pack("<3f", *m) for m in body.marker_offsets_m)
        data += b"\0\0\0\0" * len(body.marker_offsets_m)
        if version.at_least(4, 0):
            data += b"".join(f"Marker{i + 1}\0".encode() for i in range(len(body.marker_offsets_m)))
        datasets += _I32.pack(1) + (_I32.pack(len(data)) if _sized(version) else b"") + data
    return packet(NAT_MODELDEF, _I32.pack(len(bodies)) + datasets)


# ---------------------------------------------------------------- frames of data


def _section(read: _Reader, version: NatNetVersion, name: str, item_bytes: int) -> tuple[int, int]:
    """A section's item count and, from 4.1, its byte size (-1 before 4.1)."""
    count = read.count(f"{name} count", item_bytes)
    size = read.count(f"{name} size", 0) if _sized(version) else -1
    if size > read.left():
        raise read.fail(f"{name} size {size} does not fit the {read.left()} bytes left")
    return count, size


def _skip_section(read: _Reader, version: NatNetVersion, name: str, item_bytes: int) -> int:
    """Read past a section of ``item_bytes``-sized items (variable-sized ones are skipped
    by their size from 4.1 and read through before); returns its item count."""
    count, size = _section(read, version, name, item_bytes)
    if size >= 0:
        read.skip(size, name)
        return count
    for _ in range(count):
        _SKIP_ITEM[name](read)
    return count


def _skip_marker_set(read: _Reader) -> None:
    read.string("marker set name")
    read.skip(12 * read.count("marker set marker count", 12), "marker positions")


def _skip_skeleton(read: _Reader) -> None:
    read.int32("skeleton id")
    read.skip(RIGID_BODY_BYTES * read.count("skeleton bone count", RIGID_BODY_BYTES), "bones")


def _skip_channels(read: _Reader) -> None:
    read.int32("id")
    for _ in range(read.count("channel count", 4)):
        read.skip(4 * read.count("channel frame count", 4), "channel values")


_SKIP_ITEM = {
    "marker sets": _skip_marker_set,
    "legacy markers": lambda read: read.skip(12, "legacy marker"),
    "skeletons": _skip_skeleton,
    "labeled markers": lambda read: read.skip(LABELED_MARKER_BYTES, "labeled marker"),
    "force plates": _skip_channels,
    "devices": _skip_channels,
}


def _rigid_bodies(read: _Reader, version: NatNetVersion) -> tuple[RigidBody, ...]:
    count, size = _section(read, version, "rigid bodies", RIGID_BODY_BYTES)
    if size >= 0 and size != count * RIGID_BODY_BYTES:
        raise read.fail(f"{count} rigid bodies take {count * RIGID_BODY_BYTES} bytes, not {size}")
    bodies = []
    for _ in range(count):
        body_id, x, y, z, qx, qy, qz, qw, error, params = read.unpack(_BODY, "rigid body")
        if not all(math.isfinite(v) for v in (x, y, z, qx, qy, qz, qw, error)):
            raise read.fail(f"rigid body {body_id}: NaN or infinity")
        bodies.append(RigidBody(body_id, (x, y, z), (qx, qy, qz, qw), error, bool(params & 1)))
    return tuple(bodies)


def parse_frame(payload: bytes | memoryview, version: NatNetVersion) -> Frame:
    """``NAT_FRAMEOFDATA`` at ``version``: its rigid bodies and timestamps; the other
    sections are read past and counted in :attr:`Frame.skipped`."""
    _check_version(version)
    read = _Reader(payload, f"frame {version}")
    number = read.int32("frame number")
    skipped = {
        "marker sets": _skip_section(read, version, "marker sets", 8),
        "legacy markers": _skip_section(read, version, "legacy markers", 12),
    }
    bodies = _rigid_bodies(read, version)
    skipped["skeletons"] = _skip_section(read, version, "skeletons", 8)
    if version.at_least(4, 1):
        skipped["assets"] = _skip_section(read, version, "assets", 12)
    skipped["labeled markers"] = _skip_section(read, version, "labeled markers", 26)
    skipped["force plates"] = _skip_section(read, version, "force plates", 8)
    skipped["devices"] = _skip_section(read, version, "devices", 8)
    _, _, timestamp, exposure, received, transmit = read.unpack(_SUFFIX, "frame suffix")
    if not math.isfinite(timestamp):
        raise read.fail("timestamp: NaN or infinity")
    precision = read.unpack(_PRECISION, "precision timestamp") if _sized(version) else (0, 0)
    (params,) = read.unpack(_PARAMS, "frame params")
    if read.left() not in (0, 4):  # the end-of-data tag, which the Python samples do not read
        raise read.fail(f"{read.left()} bytes after the frame params")
    return Frame(
        number,
        bodies,
        timestamp,
        exposure,
        received,
        transmit,
        *precision,
        recording=bool(params & 1),
        models_changed=bool(params & 2),
        skipped={name: n for name, n in skipped.items() if n},
    )


def _empty_section(version: NatNetVersion) -> bytes:
    return _I32.pack(0) + (_I32.pack(0) if _sized(version) else b"")


def build_frame(frame: Frame, version: NatNetVersion) -> bytes:
    """``NAT_FRAMEOFDATA`` at ``version`` with ``frame``'s rigid bodies (other sections
    empty), timestamps and params, ending with the end-of-data tag as Motive does."""
    _check_version(version)
    bodies = b"".join(
        _BODY.pack(
            body.id, *body.position_m, *body.rotation, body.mean_error_m, int(body.tracking_valid)
        )
        for body in frame.rigid_bodies
    )
    payload = _I32.pack(frame.number) + _empty_section(version) * 2
    payload += _I32.pack(len(frame.rigid_bodies))
    payload += _I32.pack(len(bodies)) if _sized(version) else b""
    payload += bodies + _empty_section(version)  # skeletons
    if version.at_least(4, 1):
        payload += _empty_section(version)  # assets
    payload += _empty_section(version) * 3  # labeled markers, force plates, devices
    payload += _SUFFIX.pack(
        0,
        0,
        frame.timestamp_s,
        frame.mid_exposure_ticks,
        frame.data_received_ticks,
        frame.transmit_ticks,
    )
    if _sized(version):
        payload += _PRECISION.pack(frame.precision_seconds, frame.precision_fraction)
    params = int(frame.recording) | int(frame.models_changed) << 1
    payload += _PARAMS.pack(params) + _I32.pack(0)
    return packet(NAT_FRAMEOFDATA, payload)
