"""The wires inside one container: outputs handed to readers in the same process as objects.

A container (:mod:`ubitrack_agent.services.container`) runs many components in one process. Where
one of them reads another's output (a :class:`~ubitrack_agent.net.spec.LocalWire`: the reader's
binding key is the producer's output key), the producer hands the measurement object to the
reader, with no encoding, no decoding and no zenoh; the value is the one the producer
computed, checked finite as the codec would check it on the way out (``core.codec.encode``).
This is the intra-process communication of ROS 2's component containers and the direct calls
of Ubitrack's single-process data flow (Pustka et al. 2006, section 5: the pattern instances
of one host's data flow connected by their ports).

A hand-over happens on the producer's thread, after the producer released its lock: the
producer queues it while it holds its lock (its readers, :attr:`LocalWires.readers`, and the
value), takes its queue before it releases the lock, and delivers it (:func:`deliver`) after,
so no component ever waits for another's lock while holding its own: a reader's query for a
value at a given time (``net.time_queries``), which goes upstream to the producer, cannot
deadlock against the producer's hand-over downstream. A chain of components in one container
thus runs on the thread that took the first sample: one hand-over per hop, no thread switch,
a stack depth growing with the chain's length (O(depth)).
"""

from __future__ import annotations

import functools
import logging
import math
import operator
import struct
import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from ubitrack_agent.core import Measurement

log = logging.getLogger("ubitrack.container")

Deliver = Callable[[list[Measurement]], None]
"""A reader's input: takes values of one wire, oldest first; must not raise."""

SHORT_VALUE_FLOATS = 256
"""Up to this many numbers, :func:`finite` checks them as Python floats, as the codec does
(``core.codec.SHORT_MESSAGE_FLOATS``)."""


def finite(value: Measurement) -> bool:
    """Whether every number of ``value`` is finite: the check ``core.codec.encode`` makes of a
    result leaving the process, made here for one leaving its component. The sum of its
    numbers first (a value of a short shape: its arrays' bytes read as Python floats at once):
    an infinity or a NaN anywhere makes the sum infinite or NaN, so a finite sum proves them
    all finite; only a sum that overflows (numbers near 1e308) is looked at number by number.
    A long value's arrays are checked with numpy. A third of the time of reading each array
    apart (``docs/performance.md``, "Throughput"); the bytes joined from the arrays' buffers,
    not copied by a numpy call each (:func:`_joined`). O(numbers)."""
    arrays, numbers, short = _layout(type(value))
    present = arrays(value)
    if numbers is not None:  # every field required, of a fixed shape
        floats = numbers.unpack(_joined(present))
    elif short:
        floats = memoryview(_joined([a for a in present if a is not None])).cast("d")
    else:
        return all(bool(np.isfinite(array).all()) for array in present if array is not None)
    return math.isfinite(sum(floats)) or all(map(math.isfinite, floats))


def _joined(arrays: tuple[np.ndarray, ...] | list[np.ndarray]) -> bytes:
    """The bytes of ``arrays`` one after the other, read through the buffer protocol (no numpy
    call: a third of a hop's check on a loaded CPU); a strided view, which exports no plain
    buffer, is copied (the order of the numbers does not matter to a sum)."""
    try:
        return b"".join(arrays)
    except TypeError:  # "expected a bytes-like object": no contiguous buffer
        return b"".join(map(np.ndarray.tobytes, arrays))


@functools.cache
def _layout(
    kind: type[Measurement],
) -> tuple[Callable[[Measurement], tuple[Any, ...]], struct.Struct | None, bool]:
    """How :func:`finite` reads a measurement type: a getter of its array fields (float64:
    validated on creation) as a tuple; the layout of their bytes where every field is
    required and of a fixed shape; and whether they hold at most :data:`SHORT_VALUE_FLOATS`
    numbers whatever the value."""
    fields = kind.ARRAY_FIELDS
    names = [spec.name for spec in fields]
    sizes = [math.prod(spec.shape) if None not in spec.shape else None for spec in fields]
    short = None not in sizes and sum(sizes) <= SHORT_VALUE_FLOATS
    fixed = short and not any(spec.optional for spec in fields)
    many = len(names) > 1
    getter = operator.attrgetter(*names) if many else functools.partial(_fields, names)
    return getter, struct.Struct(f"{sum(sizes)}d") if fixed else None, short


def _fields(names: list[str], value: Measurement) -> tuple[Any, ...]:
    return tuple(getattr(value, name) for name in names)


class LocalSubscription:
    """A reader's place on a wire; :meth:`undeclare` takes it off (as a zenoh subscriber)."""

    def __init__(self, wires: LocalWires, key: str, deliver: Deliver) -> None:
        self._wires, self.key, self.deliver = wires, key, deliver

    def undeclare(self) -> None:
        self._wires._remove(self)


Handed = list[tuple[tuple[LocalSubscription, ...], Measurement]]
"""Hand-overs queued by a producer, oldest first: the readers of a key and a value of it."""


class LocalWires:
    """The outputs produced in one container and their readers there (module docstring).

    Registration (:meth:`produce`, :meth:`subscribe`) takes a lock and replaces the readers'
    tuples; a hand-over reads them without it. Memory O(outputs + readers)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._producers: dict[str, frozenset[str]] = {}
        """Data key -> the instances in this container producing it (two while a plan changes:
        ``net.spec.GroupSpec``)."""
        self.readers: dict[str, tuple[LocalSubscription, ...]] = {}
        """Data key -> its readers in the container (read without the lock: replaced whole)."""
        self._latest: dict[str, Measurement] = {}
        """The latest value handed over on each key (a static output's reader bound later
        starts from it)."""
        self.changed: Callable[[set[str]], None] = lambda keys: None
        """Called with the keys whose producer in this container came or went (by the thread
        that changed it, holding no lock of this object): their readers bind again."""

    # -- who produces, who reads ----------------------------------------------------------------

    def produce(self, instance: str, keys: list[str] | tuple[str, ...]) -> None:
        """``instance`` produces exactly ``keys`` now (its earlier keys no longer); tells
        :attr:`changed` the keys that gained their first producer here or lost their last.
        O(outputs in the container)."""
        wanted = set(keys)
        moved = set()
        with self._lock:
            before = {k for k, owners in self._producers.items() if instance in owners}
            for key in before - wanted:
                owners = self._producers[key] - {instance}
                if owners:
                    self._producers[key] = owners
                else:
                    del self._producers[key]
                    self._latest.pop(key, None)
                    moved.add(key)
            for key in wanted - before:
                owners = self._producers.get(key, frozenset())
                moved.update(() if owners else (key,))
                self._producers[key] = owners | {instance}
        if moved:
            self.changed(moved)

    def producer(self, key: str) -> str | None:
        """An instance in this container producing ``key`` (the first by name), if any."""
        owners = self._producers.get(key)
        return min(owners) if owners else None

    def subscribe(self, key: str, deliver: Deliver) -> LocalSubscription:
        subscription = LocalSubscription(self, key, deliver)
        with self._lock:
            self.readers[key] = (*self.readers.get(key, ()), subscription)
        return subscription

    def _remove(self, subscription: LocalSubscription) -> None:
        with self._lock:
            kept = tuple(s for s in self.readers.get(subscription.key, ()) if s is not subscription)
            if kept:
                self.readers[subscription.key] = kept
            else:
                self.readers.pop(subscription.key, None)

    def keep(self, key: str, value: Measurement) -> None:
        """Keep ``value`` (finite: the codec encoded it, or :func:`finite` checked it) as
        ``key``'s latest, for a reader bound later."""
        self._latest[key] = value

    def latest(self, key: str) -> Measurement | None:
        return self._latest.get(key)

    # -- hand-over ------------------------------------------------------------------------------

    def hand_over(
        self, key: str, readers: tuple[LocalSubscription, ...], value: Measurement, queue: Handed
    ) -> None:
        """Queue ``value`` of ``key`` for ``readers`` (``key``'s: :attr:`readers`) on the
        producer's ``queue``, delivered by :func:`deliver` once the producer released its lock;
        it is ``key``'s latest from now on. O(1)."""
        self._latest[key] = value
        queue.append((readers, value))


def deliver(queued: Handed) -> None:
    """Deliver what a producer queued (:meth:`LocalWires.hand_over`), in order, the consecutive
    values of one reader in one call (a run of a backlog stays a run downstream:
    ``ubitrack_agent.services.worker``); a reader's own hand-overs are delivered by the reader
    before it returns. O(values queued x their readers)."""
    pairs = [(reader.deliver, value) for readers, value in queued for reader in readers]
    reader, values = pairs[0][0], [pairs[0][1]]
    for each, value in pairs[1:]:
        if each is reader:
            values.append(value)
        else:
            reader(values)
            reader, values = each, [value]
    reader(values)
