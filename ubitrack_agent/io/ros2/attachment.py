"""The attachment rmw_zenoh puts on every sample, and without which its subscribers drop it.

rmw_zenoh (``rmw_zenoh_cpp/src/detail/attachment_helpers.cpp``) writes, with zenoh-ext's
serializer, three key-value pairs in this order: the string ``sequence_number`` and an int64
(the publisher's count, from 1), ``source_timestamp`` and an int64 (Unix nanoseconds when it
was published), ``source_gid`` and the publisher's 16-byte gid. In zenoh-ext's format a
string or byte slice is its length as an unsigned LEB128 varint followed by its bytes, an
int64 eight little-endian bytes. The unit tests check both directions against
``zenoh.ext.z_serialize`` / ``z_deserialize``.

Decoding is total: anything else raises :class:`AttachmentError`. Bytes after the three pairs
are ignored, as rmw_zenoh's reader does. O(1) per attachment.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

GID_BYTES = 16
"""``RMW_GID_STORAGE_SIZE`` since Iron."""

_KEYS = (b"sequence_number", b"source_timestamp", b"source_gid")
_INT64 = struct.Struct("<q")
_MAX_VARINT_BYTES = 10


class AttachmentError(ValueError):
    """A sample's attachment is missing or not in rmw_zenoh's layout; the message says how."""


@dataclass(frozen=True)
class Attachment:
    sequence_number: int
    source_timestamp_ns: int
    gid: bytes

    def __post_init__(self) -> None:
        if len(self.gid) != GID_BYTES:
            raise ValueError(f"a gid has {GID_BYTES} bytes, got {len(self.gid)}")


def _varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte, value = value & 0x7F, value >> 7
        out.append(byte | (0x80 if value else 0))
        if not value:
            return bytes(out)


def _sized(data: bytes) -> bytes:
    return _varint(len(data)) + data


def encode_attachment(attachment: Attachment) -> bytes:
    """The attachment's bytes, as rmw_zenoh writes them."""
    return b"".join(
        (
            _sized(_KEYS[0]),
            _INT64.pack(attachment.sequence_number),
            _sized(_KEYS[1]),
            _INT64.pack(attachment.source_timestamp_ns),
            _sized(_KEYS[2]),
            _sized(attachment.gid),
        )
    )


class _Reader:
    def __init__(self, data: bytes) -> None:
        self.data, self.at = data, 0

    def varint(self) -> int:
        value = 0
        for shift in range(0, 7 * _MAX_VARINT_BYTES, 7):
            if self.at >= len(self.data):
                raise AttachmentError("ends inside a length")
            byte = self.data[self.at]
            self.at += 1
            value |= (byte & 0x7F) << shift
            if not byte & 0x80:
                return value
        raise AttachmentError("a length longer than ten bytes")

    def take(self, size: int) -> bytes:
        if size > len(self.data) - self.at:
            raise AttachmentError(f"ends {size - (len(self.data) - self.at)} bytes early")
        chunk = self.data[self.at : self.at + size]
        self.at += size
        return chunk

    def sized(self) -> bytes:
        return self.take(self.varint())

    def int64(self) -> int:
        return _INT64.unpack(self.take(_INT64.size))[0]

    def key(self, expected: bytes) -> None:
        found = self.sized()
        if found != expected:
            raise AttachmentError(f"expected key {expected.decode()}, got {found[:40]!r}")


def decode_attachment(data: bytes | None) -> Attachment:
    """The attachment in ``data``; :class:`AttachmentError` if there is none or it is not
    rmw_zenoh's layout."""
    if data is None:
        raise AttachmentError("no attachment (rmw_zenoh subscribers drop such samples)")
    reader = _Reader(bytes(data))
    reader.key(_KEYS[0])
    sequence_number = reader.int64()
    reader.key(_KEYS[1])
    source_timestamp = reader.int64()
    reader.key(_KEYS[2])
    gid = reader.sized()
    if len(gid) != GID_BYTES:
        raise AttachmentError(f"source_gid has {len(gid)} bytes, not {GID_BYTES}")
    return Attachment(sequence_number, source_timestamp, gid)
