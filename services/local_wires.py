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
import sys
import threading
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from ubitrack_agent.core import Measurement

log = logging.getLogger("ubitrack.container")

Deliver = Callable[[list[Measurement]], None]
"""A reader's input: takes values of one wire, oldest first; must not raise."""

_HIGH_BYTE = 7 if sys.byteorder == "little" else 0
"""Where a native float64's byte holding its sign and its exponent's highest seven bits is."""


def finite(value: Measurement) -> bool:
    """Whether every number of ``value`` is finite: the check ``core.codec.encode`` makes of a
    result leaving the process, made here once for a value handed to readers in the container.
    Its arrays (native float64: validated on creation, or made so by the maths) are joined as
    bytes through the buffer protocol and the highest byte of each number looked at (a slice
    of every eighth byte): an infinity or a NaN has every exponent bit set (IEEE 754), so that
    byte is ``0x7f`` or ``0xff``; where neither occurs every number is finite. Only a value
    holding a number of magnitude 2**1009 or more (about 5e303) is read number by number. No
    numpy call and no Python float made on the way: in the chain of the hop bench (timed
    around each call, alternated value by value) 1.8-2.8 us a value against 2.3-3.5 us for
    reading the numbers as floats and summing them, as this did before (``docs/services.md``,
    "What it costs"). O(numbers)."""
    arrays, optional = _layout(type(value))
    present = arrays(value)
    if optional:
        present = [array for array in present if array is not None]
    try:
        data = b"".join(present)  # through the buffer protocol: no numpy call
    except TypeError:  # "a bytes-like object is required": a strided view, no plain buffer
        data = b"".join(map(np.ndarray.tobytes, present))  # (the order does not matter here)
    high = data[_HIGH_BYTE::8]
    if b"\x7f" not in high and b"\xff" not in high:
        return True
    return all(map(math.isfinite, memoryview(data).cast("d")))


@functools.cache
def _layout(kind: type[Measurement]) -> tuple[Callable[[Measurement], tuple[Any, ...]], bool]:
    """A getter of a measurement type's array fields, as a tuple, and whether one of them is
    optional (None when left out)."""
    fields = kind.ARRAY_FIELDS
    names = [spec.name for spec in fields]
    getter = operator.attrgetter(*names) if len(names) > 1 else functools.partial(_fields, names)
    return getter, any(spec.optional for spec in fields)


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
        self._produced: dict[str, set[str]] = {}
        """Instance -> the keys it produces (:attr:`_producers` the other way round)."""
        self.readers: dict[str, tuple[LocalSubscription, ...]] = {}
        """Data key -> its readers in the container (read without the lock: replaced whole)."""
        self._reads: dict[str, frozenset[str]] = {}
        """Instance -> the keys its inputs are bound to, here or over zenoh (:meth:`reads`)."""
        self._read_by: dict[str, set[str]] = {}
        """Data key -> the instances in this container reading it (:attr:`_reads` the other
        way round): whose inputs bind again when the key's producer comes or goes."""
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
        O(``instance``'s keys, before and now), whatever the container holds."""
        wanted = set(keys)
        moved = set()
        with self._lock:
            before = self._produced.pop(instance, set())
            if wanted:
                self._produced[instance] = wanted
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

    def reads(self, instance: str, keys: Iterable[str]) -> None:
        """``instance``'s inputs are bound to exactly ``keys`` now, locally or over zenoh (none:
        it left). O(``instance``'s keys, before and now)."""
        wanted = frozenset(keys)
        with self._lock:
            before = self._reads.pop(instance, frozenset())
            if wanted:
                self._reads[instance] = wanted
            for key in before - wanted:
                readers = self._read_by[key]
                readers.discard(instance)
                if not readers:
                    del self._read_by[key]
            for key in wanted - before:
                self._read_by.setdefault(key, set()).add(instance)

    def reading(self, keys: Iterable[str]) -> set[str]:
        """The instances in this container reading any of ``keys``. O(``keys`` + those
        instances)."""
        with self._lock:
            return set().union(*(self._read_by.get(key, ()) for key in keys))

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
