"""Wire codec: every measurement type to and from one msgpack map.

Wire format, version 1 (documented in ``docs/architecture.md``)::

    {"v": 1, "type": "<TYPE_TAG>", "t": <int ns>,
     "<array field>": <bin: little-endian float64, row-major>, ...,
     "image_size": [w, h]}                      # CameraIntrinsics only, optional

Arrays travel as raw IEEE-754 bytes, so a round trip is bit-exact and decoding a pose costs a
few microseconds. The shape of each array is fixed by the type; for lists it follows from the
byte length. Optional fields (covariances, image size) are omitted when absent. Unknown keys are
rejected, so a typo in a hand-written sensor never goes unnoticed.

:func:`decode` raises :class:`~ubitrack_agent.core.errors.MeasurementError` and nothing else,
whatever bytes it is given.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import msgpack
import numpy as np

from ubitrack_agent.core.errors import MeasurementError
from ubitrack_agent.core.measurements import (
    FULL,
    MEASUREMENT_TYPES,
    WORKER,
    ArrayField,
    CameraIntrinsics,
    Measurement,
    fixed_layout,
    is_timestamp,
    stacked_check,
)

WIRE_VERSION = 1
MAX_MESSAGE_BYTES = 32 * 1024 * 1024
"""Largest message :func:`decode` looks at (a list of a million 3D points is 24 MB)."""

_FLOAT = np.dtype("<f8")
_NATIVE = np.dtype(np.float64) == _FLOAT
"""Measurements hold native float64 arrays (C order): on a little-endian host their bytes are
the wire's as they are."""
_HEADER_KEYS = frozenset({"v", "type", "t"})
_ABSENT = object()

M = TypeVar("M", bound=Measurement)


RUN_MIN = 8
"""Samples taken together from which :func:`decode_run` is worth it (a worker's backlog,
``ubitrack_agent.services.worker``): below it a run's numpy calls cost about what they save."""
SHORT_MESSAGE_FLOATS = 256
"""Up to this many numbers, :func:`_all_finite` checks them as Python floats."""


def _all_finite(data: bytes) -> bool:
    """Whether every float64 in ``data`` (the raw arrays of one message, joined) is finite. A
    short message's (a pose, its covariance) as Python floats: numpy's ufunc and its reduction
    would be two more code paths for a hop to run through with cold caches
    (``docs/performance.md``, "Data path"); a long one's with numpy."""
    if _NATIVE and len(data) <= SHORT_MESSAGE_FLOATS * _FLOAT.itemsize:
        return all(map(math.isfinite, memoryview(data).cast("d")))
    return bool(np.isfinite(np.frombuffer(data, dtype=_FLOAT)).all())


def encode(measurement: Measurement) -> bytes:
    """Serialise ``measurement`` to msgpack bytes (see the module docstring for the format).

    Raises :class:`MeasurementError` if it holds NaN or infinity: a result of this package's
    maths is checked here, once, where it leaves the process (``core.measurements.DERIVED``).
    """
    message: dict[str, Any] = {
        "v": WIRE_VERSION,
        "type": measurement.TYPE_TAG,
        "t": measurement.timestamp_ns,
    }
    parts = []
    for spec in measurement.ARRAY_FIELDS:
        value = getattr(measurement, spec.name)
        if value is not None:
            data = value.tobytes() if _NATIVE else value.astype(_FLOAT).tobytes()
            message[spec.name] = data
            parts.append(data)
    if not _all_finite(b"".join(parts)):
        raise MeasurementError(f"{measurement.TYPE_TAG}: contains NaN or infinity, not encoded")
    if isinstance(measurement, CameraIntrinsics) and measurement.image_size is not None:
        message["image_size"] = list(measurement.image_size)
    return msgpack.packb(message)  # use_bin_type=True: msgpack's default since 1.0


def _unpack(data: Any) -> dict[str, Any]:
    if type(data) is not bytes:  # a subscriber's payload is bytes: decided at once
        if not isinstance(data, bytearray | memoryview):
            raise MeasurementError(f"message: expected bytes, got {type(data).__name__}")
        data = bytes(data)
    if len(data) > MAX_MESSAGE_BYTES:
        raise MeasurementError(f"message: {len(data)} bytes exceeds {MAX_MESSAGE_BYTES}")
    try:
        # msgpack's defaults since 1.0 (pyproject.toml): raw=False (text as str), and
        # strict_map_key=True (keys only str or bytes): tested in tests/unit/test_codec.py.
        message = msgpack.unpackb(data)
    except Exception as exc:  # msgpack raises a dozen unrelated types for garbage input
        raise MeasurementError(f"message: not valid msgpack ({type(exc).__name__})") from None
    if type(message) is not dict:
        raise MeasurementError(f"message: expected a map, got {type(message).__name__}")
    return message


def _array(tag: str, spec: ArrayField, raw: Any) -> np.ndarray:
    """Field ``spec`` of a ``tag`` message from its ``raw`` value: a fixed shape's exact bytes
    (the common case, first), or a list's whole number of rows; else the error naming it."""
    if type(raw) is bytes and len(raw) == spec.fixed_bytes:
        flat = np.frombuffer(raw, dtype=_FLOAT)
        return flat if len(spec.shape) == 1 else flat.reshape(spec.shape)
    where, shape = f"{tag}.{spec.name}", spec.shape
    if type(raw) is not bytes:
        raise MeasurementError(f"{where}: expected float64 bytes, got {type(raw).__name__}")
    if None in shape and len(raw) % _FLOAT.itemsize == 0:  # a list: any whole multiple
        flat = np.frombuffer(raw, dtype=_FLOAT)
        fixed = math.prod(d for d in shape if d is not None)
        if fixed and flat.size % fixed == 0:
            return flat.reshape([flat.size // fixed if d is None else d for d in shape])
    if len(raw) % _FLOAT.itemsize:
        raise MeasurementError(f"{where}: {len(raw)} bytes is not a whole number of float64")
    raise MeasurementError(
        f"{where}: {len(raw) // _FLOAT.itemsize} values do not fit shape {shape}"
    )


@functools.cache
def _known_keys(cls: type[Measurement]) -> frozenset[str]:
    """The keys a message of type ``cls`` may hold."""
    extra = {"image_size"} if cls is CameraIntrinsics else set()
    return _HEADER_KEYS | {spec.name for spec in cls.ARRAY_FIELDS} | extra


@dataclass(frozen=True)
class _Canonical:
    """How to read a message of a type whose arrays all have fixed shapes when it holds
    exactly the header and every field (or every required field: :meth:`of`), each the exact
    number of bytes: what every encoder of this package sends. :func:`decode` reads such a
    message here, in one pass over precomputed names and sizes; anything else (and any doubt)
    goes to the general reader, which names what is wrong. Both accept the same messages and
    build the same values (``tests/unit/test_codec.py``); this one exists because a pattern
    hop decodes every sample and pays for each step on a CPU woken for it
    (``docs/performance.md``, "Data path")."""

    cls: type[Measurement]
    names: tuple[str, ...]
    absent: dict[str, None]
    """The type's optional fields this reader's messages leave out, each None."""
    sizes: list[int]
    """Each field's size in bytes (a list, compared with a list of lengths at once)."""
    shapes: tuple[tuple[int, ...] | None, ...]
    """Each field's shape, None for a vector (``np.frombuffer``'s own)."""
    checks: dict[str, tuple[tuple[str, str, Callable[[str, np.ndarray], None]], ...]]
    """By validation level: each field's check with the name it gives in an error."""

    @classmethod
    def of(cls, measurement: type[Measurement]) -> list[_Canonical]:
        """The readers for ``measurement``, none unless it has a :func:`fixed_layout`: one for
        messages with every optional field, one (if it has any) for those without any (what an
        encoder writes of a value that left them out: a pose's static part, a position's
        covariance). Each holds a different number of keys, which picks it."""
        layout = fixed_layout(measurement)
        if layout is None:
            return []
        every = measurement.ARRAY_FIELDS
        required = tuple(spec for spec in every if not spec.optional)
        variants = (every, required) if len(required) < len(every) else (every,)
        return [cls._for(measurement, specs) for specs in variants]

    @classmethod
    def _for(cls, measurement: type[Measurement], specs: tuple[ArrayField, ...]) -> _Canonical:
        """The reader of ``measurement``'s messages holding exactly the fields ``specs``."""
        tag = measurement.__name__
        absent = {spec.name: None for spec in measurement.ARRAY_FIELDS if spec not in specs}
        checks = {
            level: tuple(
                (spec.name, f"{tag}.{spec.name}", check)
                for spec in specs
                if (check := spec.check_at(level)) is not None
            )
            for level in (FULL, WORKER)
        }
        return cls(
            measurement,
            tuple(spec.name for spec in specs),
            absent,
            [spec.fixed_bytes for spec in specs],  # type: ignore[misc]
            tuple(None if len(spec.shape) == 1 else spec.shape for spec in specs),  # type: ignore[misc]
            checks,
        )

    @property
    def keys(self) -> int:
        """How many keys a message this reader reads holds."""
        return len(_HEADER_KEYS) + len(self.names)

    def fields(self, message: dict[str, Any]) -> tuple[int, list[bytes], bytes] | None:
        """The timestamp, the fields' bytes and those joined, of ``message`` (whose ``type``
        is this reader's) as an encoder writes it; None if anything is not exactly as
        expected (its numbers not looked at yet)."""
        if len(message) != len(_HEADER_KEYS) + len(self.names):
            return None
        try:  # as many keys as expected: one missing means an unknown one is there instead
            version, timestamp = message["v"], message["t"]
            raws = [message[name] for name in self.names]
        except KeyError:
            return None
        if not (type(version) is int and version == WIRE_VERSION and is_timestamp(timestamp)):
            return None
        try:  # bytes only: msgpack gives no other buffer type, and join refuses anything else
            joined = b"".join(raws)
        except TypeError:
            return None
        if list(map(len, raws)) != self.sizes:
            return None
        return timestamp, raws, joined

    def read(self, message: dict[str, Any], level: str) -> Measurement | None:
        """The measurement in ``message`` (whose ``type`` is this reader's) validated at
        ``level``; None if anything is not exactly as expected; ``MeasurementError`` from a
        field's check (the general reader's error: same check, same order, same name)."""
        found = self.fields(message)
        return None if found is None else self._checked(found, level)

    def _checked(self, found: tuple[int, list[bytes], bytes], level: str) -> Measurement | None:
        timestamp, raws, joined = found
        if not _all_finite(joined):
            return None
        value = self._built(timestamp, [np.frombuffer(raw, dtype=_FLOAT) for raw in raws])
        for name, where, check in self.checks.get(level, ()):
            check(where, value.__dict__[name])
        return value

    def _built(self, timestamp: int, flats: list[np.ndarray]) -> Measurement:
        """The measurement of ``timestamp`` and its fields' values, flat and read-only."""
        value = object.__new__(self.cls)
        values = value.__dict__  # a frozen dataclass: set here, once, before anyone uses it
        values["timestamp_ns"] = timestamp
        for name, shape, flat in zip(self.names, self.shapes, flats, strict=True):
            values[name] = flat if shape is None else flat.reshape(shape)
        if self.absent:
            values.update(self.absent)
        return value

    def read_run(
        self, found: list[tuple[int, list[bytes], bytes]], level: str
    ) -> list[Measurement | MeasurementError | None]:
        """For several messages' :meth:`fields`, what :meth:`read` gives each: the
        measurement, None, or the error its check raises (returned, not raised). Their
        numbers are tested for finiteness by one numpy call over all of them, and each
        field's check by its stacked form over the run where it has one
        (``core.measurements.stacked_check``); only where that fails is each checked alone,
        in the single reader's order, so each gets the error the single reader gives it."""
        count = len(found)
        flat = np.frombuffer(b"".join(joined for _, _, joined in found), dtype=_FLOAT)
        if not np.isfinite(flat).all():  # some message to the general reader: each alone
            return [self._checked_or_error(one, level) for one in found]
        rows = flat.reshape(count, -1)
        columns, start = [], 0
        for size in self.sizes:
            columns.append(rows[:, start : start + size // _FLOAT.itemsize])
            start += size // _FLOAT.itemsize
        results: list[Measurement | MeasurementError | None] = [
            self._built(timestamp, [column[j] for column in columns])
            for j, (timestamp, _, _) in enumerate(found)
        ]
        for name, where, check in self.checks.get(level, ()):
            field = self.names.index(name)
            column, shape, stacked = columns[field], self.shapes[field], stacked_check(check)
            if stacked is not None and stacked(
                column if shape is None else column.reshape(count, *shape)
            ):
                continue
            for j, value in enumerate(results):
                if isinstance(value, Measurement):
                    try:
                        check(where, value.__dict__[name])
                    except MeasurementError as exc:
                        results[j] = exc
        return results

    def _checked_or_error(
        self, found: tuple[int, list[bytes], bytes], level: str
    ) -> Measurement | MeasurementError | None:
        try:
            return self._checked(found, level)
        except MeasurementError as exc:
            return exc


_CANONICAL: dict[tuple[str, int], _Canonical] = (
    {
        (tag, reader.keys): reader
        for tag, cls in MEASUREMENT_TYPES.items()
        for reader in _Canonical.of(cls)
    }
    if _NATIVE
    else {}
)
"""The canonical readers by type tag and number of keys (none on a big-endian host, whose
arrays are converted)."""


def decode(
    data: Any, expected: type[M] | tuple[type[M], ...] | None = None, level: str = FULL
) -> M:
    """Parse one message and validate it at ``level`` (``core.measurements``: ``FULL`` for a
    value from outside, ``WORKER`` for a known worker's output); optionally require it to be
    of the ``expected`` type(s).

    Raises :class:`MeasurementError` naming the field at fault for anything else.
    """
    message = _unpack(data)
    canonical = _canonical(message, expected)
    if canonical is not None:
        value = canonical.read(message, level)
        if value is not None:
            return value  # type: ignore[return-value]
    return _read(message, expected, level)


def decode_run(
    payloads: Sequence[Any],
    expected: type[M] | tuple[type[M], ...] | None = None,
    level: str = FULL,
) -> list[M | MeasurementError]:
    """Each of ``payloads`` as :func:`decode` decodes it: the same measurement, or the
    :class:`MeasurementError` it raises (returned in its place). For a worker draining a
    backlog (``ubitrack_agent.services.worker``): the messages of one type an encoder wrote are
    checked together (:meth:`_Canonical.read_run`), a numpy call per check for the whole run instead
    of one per message; anything else goes to the general reader one by one."""
    results: list[Any] = [None] * len(payloads)
    messages: dict[int, dict[str, Any]] = {}
    runs: dict[tuple[str, int], list[tuple[int, tuple[int, list[bytes], bytes]]]] = {}
    for i, data in enumerate(payloads):
        try:
            message = messages[i] = _unpack(data)
        except MeasurementError as exc:
            results[i] = exc
            continue
        canonical = _canonical(message, expected)
        found = None if canonical is None else canonical.fields(message)
        if found is not None:
            runs.setdefault((message["type"], len(message)), []).append((i, found))
    for reader, members in runs.items():
        values = _CANONICAL[reader].read_run([found for _, found in members], level)
        for (i, _), value in zip(members, values, strict=True):
            results[i] = value
    for i, message in messages.items():
        if results[i] is None:
            try:
                results[i] = _read(message, expected, level)
            except MeasurementError as exc:
                results[i] = exc
    return results


def _canonical(
    message: dict[str, Any], expected: type[Measurement] | tuple[type[Measurement], ...] | None
) -> _Canonical | None:
    """The canonical reader of ``message``'s type if it is one ``expected``, else None."""
    tag = message.get("type")
    canonical = _CANONICAL.get((tag, len(message))) if type(tag) is str else None
    if canonical is not None and (expected is None or issubclass(canonical.cls, expected)):
        return canonical
    return None


def _read(message: dict[str, Any], expected: type[M] | tuple[type[M], ...] | None, level: str) -> M:
    """The general reader of :func:`decode`: any message, each defect named."""
    version = message.get("v")
    if type(version) is not int or version != WIRE_VERSION:
        raise MeasurementError(f"message.v: unsupported wire version {str(version)[:40]!r}")
    tag = message.get("type")
    cls = MEASUREMENT_TYPES.get(tag) if isinstance(tag, str) else None
    if cls is None:
        raise MeasurementError(f"message.type: unknown measurement type {str(tag)[:40]!r}")
    if expected is not None and not issubclass(cls, expected):
        names = [c.__name__ for c in (expected if isinstance(expected, tuple) else (expected,))]
        raise MeasurementError(f"message.type: expected {' or '.join(names)}, got {tag}")
    if "t" not in message:
        raise MeasurementError(f"{tag}.timestamp_ns: missing key 't'")
    unknown = message.keys() - _known_keys(cls)
    if unknown:
        raise MeasurementError(f"{tag}: unknown keys {sorted(str(k)[:40] for k in unknown)}")
    kwargs: dict[str, Any] = {"timestamp_ns": message["t"]}
    raws = []
    for spec in cls.ARRAY_FIELDS:
        raw = message.get(spec.name, _ABSENT)
        if raw is _ABSENT:
            if not spec.optional:
                raise MeasurementError(f"{tag}.{spec.name}: missing")
            continue
        kwargs[spec.name] = _array(tag, spec, raw)
        raws.append(raw)
    if "image_size" in message:
        size = message["image_size"]
        kwargs["image_size"] = tuple(size) if isinstance(size, list) else size
    # If a number is not finite, the measurement's own check names the field.
    return cls.checked(level, finite=_all_finite(b"".join(raws)), **kwargs)  # type: ignore[return-value]


def to_json(measurement: Measurement) -> dict[str, Any]:
    """A JSON-ready dict of ``measurement`` (arrays as nested lists), for printing and logs."""
    data: dict[str, Any] = {"type": measurement.TYPE_TAG, "timestamp_ns": measurement.timestamp_ns}
    for spec in measurement.ARRAY_FIELDS:
        value = getattr(measurement, spec.name)
        if value is not None:
            data[spec.name] = value.tolist()
    if isinstance(measurement, CameraIntrinsics) and measurement.image_size is not None:
        data["image_size"] = list(measurement.image_size)
    return data
