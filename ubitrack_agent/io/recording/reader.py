"""Reading a recording back, every record checked: a malformed file raises
:class:`~.layout.RecordingError` saying where and why, and nothing else, whatever its bytes.

:func:`read_recording` reads the file from its start, record by record (MCAP's stream reader,
CRCs checked), so a file whose recorder was killed before it wrote the summary is read up to
where it ends and then reported as truncated; it yields the recording's events in the order they
were written (:class:`Announcement`, :class:`Withdrawal`, :class:`Sample`). It checks that
the file has the :data:`~.layout.PROFILE` profile, that the channels it replays have the
encodings and schemas of the layout, that every announcement is a valid fragment
(:mod:`.fragments`), that every measurement decodes (``core.codec.decode``, which rejects
anything malformed) to the type its edge was announced with, and that it belongs to a provider
announced at that point. Channels of other topics are skipped (a viewer's additions); the
``foxglove.FrameTransform`` channels are derived data and skipped too. Bounds: a record at most
:data:`MAX_RECORD_BYTES`, a decompressed chunk at most :data:`MAX_CHUNK_BYTES`; chunks are
zstd-compressed or not at all (an lz4 chunk's size is not bounded before it is decompressed).
O(messages) time, O(channels + edges) memory.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, BinaryIO

from mcap.records import Channel, Chunk, DataEnd, Footer, Header, Message, Schema
from mcap.stream_reader import StreamReader, breakup_chunk

from ubitrack_agent.core import Measurement, MeasurementError, decode
from ubitrack_agent.core.names import shown
from ubitrack_agent.io.provider import EdgeAnnouncement
from ubitrack_agent.io.recording.fragments import Announced, parse_fragment
from ubitrack_agent.io.recording.layout import (
    ANNOUNCEMENT_SCHEMA_NAME,
    ANNOUNCEMENTS_TOPIC,
    DATA_TOPIC_PREFIX,
    FORMAT_VERSION,
    PROFILE,
    RecordingError,
)
from ubitrack_agent.net.json_messages import MessageError, load_object

MAX_RECORD_BYTES = 64 * 1024 * 1024
MAX_CHUNK_BYTES = 64 * 1024 * 1024
MAX_ANNOUNCEMENT_BYTES = 1 << 20
CHUNK_COMPRESSIONS = ("", "zstd")


@dataclass(frozen=True)
class Announcement:
    """A provider announced its edges at ``log_time_ns`` (when the recorder saw it)."""

    log_time_ns: int
    announced: Announced


@dataclass(frozen=True)
class Withdrawal:
    """A provider's liveliness token went at ``log_time_ns``."""

    log_time_ns: int
    provider: str


@dataclass(frozen=True)
class Sample:
    """One measurement of edge ``edge_name`` of ``provider``, received at ``log_time_ns``."""

    log_time_ns: int
    provider: str
    edge_name: str
    measurement: Measurement


Event = Announcement | Withdrawal | Sample


@dataclass(frozen=True)
class Contents:
    """What a recording holds: its providers, samples and the span of its log times (s)."""

    providers: tuple[str, ...]
    samples: int
    seconds: float


def check_recording(stream: BinaryIO) -> Contents:
    """Read the whole recording in ``stream``, checking it (:func:`read_recording`): what it
    holds, or :class:`~.layout.RecordingError`."""
    providers, samples, first, last = set(), 0, None, None
    for event in read_recording(stream):
        first = event.log_time_ns if first is None else first
        last = event.log_time_ns
        if isinstance(event, Sample):
            samples += 1
        elif isinstance(event, Announcement):
            providers.add(event.announced.provider)
    span = (last - first) / 1e9 if first is not None and last is not None else 0.0
    return Contents(tuple(sorted(providers)), samples, span)


@dataclass(frozen=True)
class _DataChannel:
    provider: str
    edge_name: str
    type: str


def read_recording(stream: BinaryIO) -> Iterator[Event]:
    """The events of the recording in ``stream`` (opened for binary reading), checked."""
    records = StreamReader(
        stream, emit_chunks=True, validate_crcs=True, record_size_limit=MAX_RECORD_BYTES
    ).records
    state = _State()
    index = 0
    while True:
        try:
            record = next(records)
        except StopIteration:
            return
        except Exception as exc:  # the mcap library's parsing of untrusted bytes: any fault
            raise _unreadable(exc, stream) from None
        index += 1
        if isinstance(record, Chunk):
            if record.compression not in CHUNK_COMPRESSIONS:
                raise RecordingError(
                    f"record {index}: chunk compression {shown(record.compression)} is not "
                    f"one of {CHUNK_COMPRESSIONS}"
                )
            if not 0 <= record.uncompressed_size <= MAX_CHUNK_BYTES:
                raise RecordingError(
                    f"record {index}: a chunk of {record.uncompressed_size} bytes, more than "
                    f"{MAX_CHUNK_BYTES}"
                )
            try:
                inner = breakup_chunk(record, validate_crc=True)
            except Exception as exc:  # the same library on the chunk's bytes
                raise RecordingError(f"record {index}: unreadable chunk ({_named(exc)})") from None
        else:
            inner = [record]
        for item in inner:
            event = state.read(item)
            if event is not None:
                yield event
        if isinstance(record, Footer | DataEnd) and state.header is None:
            raise RecordingError("no header record before the end of the data")


class _State:
    """What the records read so far declared: header, schemas, channels, live providers."""

    def __init__(self) -> None:
        self.header: Header | None = None
        self.schemas: dict[int, Schema] = {}
        self.announcements: int | None = None
        self.data: dict[int, _DataChannel] = {}
        self.known: set[int] = set()
        self.live: dict[str, dict[str, EdgeAnnouncement]] = {}
        self.messages = 0

    def read(self, record: Any) -> Event | None:
        if isinstance(record, Header):
            if record.profile != PROFILE:
                raise RecordingError(
                    f"not a ubitrack recording: MCAP profile {shown(record.profile)}, expected "
                    f"{PROFILE!r} (files of `ubitrack record`)"
                )
            self.header = record
        elif self.header is None:
            raise RecordingError("the first record is not the header")
        elif isinstance(record, Schema):
            self.schemas[record.id] = record
        elif isinstance(record, Channel):
            self._channel(record)
        elif isinstance(record, Message):
            self.messages += 1
            return self._message(record)
        return None

    def _channel(self, channel: Channel) -> None:
        where = f"channel {shown(channel.topic)}"
        if channel.id in self.known:
            return  # a repeated channel record (MCAP repeats them in the summary)
        if channel.topic == ANNOUNCEMENTS_TOPIC:
            schema = self.schemas.get(channel.schema_id)
            if (
                channel.message_encoding != "json"
                or schema is None
                or schema.name != ANNOUNCEMENT_SCHEMA_NAME
                or schema.encoding != "jsonschema"
            ):
                raise RecordingError(
                    f"{where}: wrong schema or encoding (expected json messages of schema "
                    f"{ANNOUNCEMENT_SCHEMA_NAME})"
                )
            if self.announcements is not None:
                raise RecordingError(f"{where}: declared twice")
            self.announcements = channel.id
        elif channel.topic.startswith(DATA_TOPIC_PREFIX):
            meta = channel.metadata
            if (
                channel.message_encoding != "msgpack"
                or meta.get("format_version") != FORMAT_VERSION
            ):
                raise RecordingError(
                    f"{where}: wrong encoding or version (expected msgpack, format version "
                    f"{FORMAT_VERSION})"
                )
            if not {"provider", "edge", "type"} <= set(meta):
                raise RecordingError(f"{where}: metadata lacks provider, edge or type")
            if channel.topic != f"{DATA_TOPIC_PREFIX}{meta['provider']}/{meta['edge']}":
                raise RecordingError(f"{where}: topic and metadata name different edges")
            self.data[channel.id] = _DataChannel(meta["provider"], meta["edge"], meta["type"])
        self.known.add(channel.id)

    def _message(self, message: Message) -> Event | None:
        where = f"message {self.messages}"
        if message.channel_id not in self.known:
            raise RecordingError(f"{where}: on channel {message.channel_id}, never declared")
        if message.channel_id == self.announcements:
            return self._announcement(where, message)
        channel = self.data.get(message.channel_id)
        if channel is None:
            return None  # a frame transform, or another tool's channel
        where = f"{where} (edge {shown(channel.provider)}/{shown(channel.edge_name)})"
        edge = self.live.get(channel.provider, {}).get(channel.edge_name)
        if edge is None:
            raise RecordingError(f"{where}: no provider announced the edge before it")
        if edge.type != channel.type:
            raise RecordingError(
                f"{where}: channel of type {shown(channel.type)}, edge {edge.type}"
            )
        try:
            value = decode(message.data)
        except MeasurementError as exc:
            raise RecordingError(f"{where}: {exc}") from None
        if edge.type != value.SRG_TYPE:
            raise RecordingError(f"{where}: a {type(value).__name__} on a {edge.type} edge")
        return Sample(message.log_time, channel.provider, channel.edge_name, value)

    def _announcement(self, where: str, message: Message) -> Announcement | Withdrawal:
        try:
            event = load_object(message.data, MAX_ANNOUNCEMENT_BYTES)
        except MessageError as exc:
            raise RecordingError(f"{where}: announcement {exc.reason}") from None
        kind, provider = event.get("event"), event.get("provider")
        if kind == "withdrawn" and set(event) == {"event", "provider"} and provider in self.live:
            del self.live[provider]
            return Withdrawal(message.log_time, provider)
        if kind != "announced" or set(event) != {"event", "provider", "fragment"}:
            raise RecordingError(
                f"{where}: expected an announcement of a provider or the withdrawal of an "
                f"announced one, got event {shown(kind)} of provider {shown(provider)}"
            )
        try:
            announced = parse_fragment(event["fragment"], provider)
        except RecordingError as exc:
            raise RecordingError(f"{where}: {exc}") from None
        self.live[announced.provider] = {edge.name: edge for edge in announced.edges}
        return Announcement(message.log_time, announced)


def _named(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__


def _unreadable(exc: BaseException, stream: BinaryIO) -> RecordingError:
    """The error for a fault the MCAP reader met: one at the end of the file (a short read)
    means the file is truncated."""
    try:
        at_end = stream.read(1) == b""
    except (OSError, ValueError):
        at_end = False
    if at_end:
        return RecordingError(
            "the file ends inside a record: truncated (was the recorder killed before it "
            "finished?); `ubitrack record` finishes the file on Ctrl-C or SIGTERM"
        )
    return RecordingError(f"unreadable MCAP data ({_named(exc)})")
