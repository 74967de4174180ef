"""The wires inside one container: outputs handed to readers in the same process as objects.

A container (:mod:`services.container`) runs many components in one process. Where one of
them reads another's output (a :class:`~ubitrack_agent.net.spec.LocalWire`: the reader's
binding key is the producer's output key), the producer hands the measurement object to the
reader, with no encoding, no decoding and no zenoh; the value is the one the producer
computed, checked finite as the codec would check it on the way out (``core.codec.encode``).
This is the intra-process communication of ROS 2's component containers and the direct calls
of Ubitrack's single-process data flow (Pustka et al. 2006, section 5: the pattern instances
of one host's data flow connected by their ports).

A hand-over happens on the producer's thread, after the producer released its lock
(:meth:`LocalWires.hand_over` queues it for the thread, :meth:`LocalWires.flush` delivers),
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
import threading
from collections.abc import Callable

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
    numbers first (a value of a fixed, short shape as Python floats, a long one's with numpy):
    an infinity or a NaN anywhere makes the sum infinite or NaN, so a finite sum proves them
    all finite; only a sum that overflows (numbers near 1e308) is looked at number by number.
    About a quarter of the time of checking each (``docs/performance.md``, "Throughput").
    O(numbers)."""
    names, short = _layout(type(value))
    arrays = [array for name in names if (array := getattr(value, name)) is not None]
    if short:
        numbers = memoryview(b"".join([array.tobytes() for array in arrays])).cast("d")
        return math.isfinite(sum(numbers)) or all(map(math.isfinite, numbers))
    return all(bool(np.isfinite(array).all()) for array in arrays)


@functools.cache
def _layout(kind: type[Measurement]) -> tuple[tuple[str, ...], bool]:
    """The names of a measurement type's array fields (float64: validated on creation), and
    whether they hold at most :data:`SHORT_VALUE_FLOATS` numbers whatever the value."""
    sizes = [
        math.prod(spec.shape) if None not in spec.shape else None for spec in kind.ARRAY_FIELDS
    ]
    short = None not in sizes and sum(sizes) <= SHORT_VALUE_FLOATS
    return tuple(spec.name for spec in kind.ARRAY_FIELDS), short


class LocalSubscription:
    """A reader's place on a wire; :meth:`undeclare` takes it off (as a zenoh subscriber)."""

    def __init__(self, wires: LocalWires, key: str, deliver: Deliver) -> None:
        self._wires, self.key, self.deliver = wires, key, deliver

    def undeclare(self) -> None:
        self._wires._remove(self)


class LocalWires:
    """The outputs produced in one container and their readers there (module docstring).

    Registration (:meth:`produce`, :meth:`subscribe`) takes a lock and replaces the readers'
    tuples; a hand-over reads them without it. Memory O(outputs + readers)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._producers: dict[str, frozenset[str]] = {}
        """Data key -> the instances in this container producing it (two while a plan changes:
        ``net.spec.GroupSpec``)."""
        self._readers: dict[str, tuple[LocalSubscription, ...]] = {}
        self._latest: dict[str, Measurement] = {}
        """The latest value handed over on each key (a static output's reader bound later
        starts from it)."""
        self._queued: dict[int, list[tuple[Deliver, Measurement]]] = {}
        """By thread (``threading.get_ident``), the hand-overs it queued and has not flushed."""
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
            self._readers[key] = (*self._readers.get(key, ()), subscription)
        return subscription

    def _remove(self, subscription: LocalSubscription) -> None:
        with self._lock:
            kept = tuple(
                s for s in self._readers.get(subscription.key, ()) if s is not subscription
            )
            if kept:
                self._readers[subscription.key] = kept
            else:
                self._readers.pop(subscription.key, None)

    def has_readers(self, key: str) -> bool:
        return key in self._readers

    def keep(self, key: str, value: Measurement) -> None:
        """Keep ``value`` (finite: the codec encoded it) as ``key``'s latest, for a reader
        bound later, where no reader in the container took it."""
        self._latest[key] = value

    def latest(self, key: str) -> Measurement | None:
        return self._latest.get(key)

    # -- hand-over ------------------------------------------------------------------------------

    def hand_over(self, key: str, value: Measurement) -> None:
        """Queue ``value`` of ``key`` for its readers, delivered by this thread's next
        :meth:`flush` (the producer calls it holding its lock, flushes after releasing it)."""
        self._latest[key] = value
        readers = self._readers.get(key)
        if not readers:
            return
        ident = threading.get_ident()
        queued = self._queued.get(ident)
        if queued is None:
            queued = self._queued[ident] = []
        for reader in readers:
            queued.append((reader.deliver, value))

    def flush(self) -> None:
        """Deliver what this thread queued, in order, the consecutive values of one reader in
        one call (a run of a backlog stays a run downstream: ``services.worker``); a reader's
        own hand-overs are flushed by the reader before it returns. O(values queued)."""
        queued = self._queued.pop(threading.get_ident(), None)
        if not queued:
            return
        deliver, values = queued[0][0], [queued[0][1]]
        for reader, value in queued[1:]:
            if reader is deliver:
                values.append(value)
            else:
                deliver(values)
                deliver, values = reader, [value]
        deliver(values)
