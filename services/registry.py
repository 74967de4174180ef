"""The registry of pattern services: the only things a worker (and so the agent) will run.

A template names a service by its registered name; nothing received from the network is ever
imported or executed. Each service declares its input ports (with the measurement types each
accepts and whether the port takes a list of corresponding edges, i.e. a space-expanded
correspondence, paper section 3.3) and its output ports, and computes outputs from inputs that
the worker runtime has already synchronised to one timestamp.
"""

from __future__ import annotations

import functools
import importlib
import pkgutil
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

from ubitrack_agent.core import Measurement
from ubitrack_agent.net.progress import Progress


@dataclass(frozen=True)
class Port:
    """An input port and the measurement types it accepts."""

    types: tuple[type[Measurement], ...]


Inputs = Mapping[str, Measurement | list[Measurement]]


@dataclass(frozen=True)
class Pushed:
    """What an asynchronous service made of one input sample (:meth:`Service.push`): the
    outputs to publish at once, or none and the worker counter saying why (``gated``,
    ``late``, ``dropped_stale``: ``ubitrack_agent.services.worker.COUNTERS``)."""

    outputs: dict[str, Measurement] = field(default_factory=dict)
    reason: str = "no_output"


class Service(ABC):
    """Base class of a registered pattern service.

    ``compute`` gets one value per port, or an aligned list per correspondence port (below),
    all evaluated at ``timestamp_ns``, and returns the measurements to publish by output port
    (possibly none). It raises ``ValueError`` for input it cannot use (degenerate geometry);
    the worker counts and logs that and carries on.
    """

    NAME: ClassVar[str]
    INPUTS: ClassVar[dict[str, Port]]
    OUTPUTS: ClassVar[tuple[str, ...]]
    CORRESPONDENCE: ClassVar[tuple[str, ...]] = ()
    """Ports forming the correspondence set (section 3.3). Under space expansion each takes
    several bindings (in correspondence order) and ``compute`` gets aligned lists, with
    ``None`` where an input had no value at the trigger's time; under time expansion each takes
    one binding and :mod:`ubitrack_agent.services.expansion` builds the lists from accumulated
    samples."""
    MIN_CORRESPONDENCES: ClassVar[int] = 1
    """The lower bound of the correspondence's multiplicity (``3..*`` -> 3)."""
    INCREMENTAL: ClassVar[bool] = False
    """Under time expansion, ``compute`` gets only the correspondence values that are new since
    its last call (lists of one) and keeps its own running summary of the earlier ones (an
    information-form estimator), instead of the whole accumulated history."""
    TIME_MIN_MOTION: ClassVar[float] = 0.0
    TIME_MIN_ROTATION_DEG: ClassVar[float] = 0.0
    """Default distinctness thresholds under time expansion
    (:mod:`ubitrack_agent.services.expansion`)."""

    def __init__(self, parameters: Mapping[str, Any]) -> None:
        unknown = sorted(set(parameters) - set(self.PARAMETERS))
        if unknown:
            raise ValueError(f"{self.NAME}: unknown parameters {unknown}")
        self.parameters = {**self.PARAMETERS, **parameters}

    PARAMETERS: ClassVar[dict[str, Any]] = {}
    """Accepted parameters with their defaults."""

    @abstractmethod
    def compute(self, values: Inputs, timestamp_ns: int) -> dict[str, Measurement]:
        """Outputs by port for inputs synchronised to ``timestamp_ns``."""

    def compute_run(
        self, values: Sequence[Inputs], timestamps: Sequence[int]
    ) -> list[dict[str, Measurement]]:
        """The outputs of several instants at once, equal to :meth:`compute`'s one by one to
        round-off: for a worker draining a backlog of its one dynamic input
        (``ubitrack_agent.services.worker``). A service whose maths vectorise overrides it
        (:class:`~ubitrack_agent.services.components.basic.Concatenation`); it must leave the
        service's state as it was, since on an error the worker computes the instants one by one.
        Not overridden, the worker calls :meth:`compute` for each instant."""
        raise NotImplementedError(f"{self.NAME} computes one instant at a time")

    def asynchronous(self) -> bool:
        """Whether this instance takes every input sample as it arrives (:meth:`push`) instead
        of inputs synchronised at a trigger's time (:meth:`compute`); a parameter may choose."""
        return False

    def push(self, port: str, sample: Measurement, source: str = "") -> Pushed:
        """An asynchronous service's update by one sample of ``port``, in arrival order
        (timestamps may go back); ``ValueError`` for a sample it cannot use. ``source``: the
        key it arrived on (the worker's binding), which tells a correspondence's inputs apart
        (the fusion considers each one's static error on its own)."""
        raise NotImplementedError(f"{self.NAME} is not asynchronous")

    def value_at(self, port: str, timestamp_ns: int) -> Measurement:
        """An asynchronous service's output ``port`` at ``timestamp_ns`` from its own state (a
        filter's motion model), for a query at a given time (``net.time_queries``); raises
        ``ExtrapolationError`` or ``NoDataError`` where it has no answer."""
        raise NotImplementedError(f"{self.NAME} is not asynchronous")

    def min_correspondences(self) -> int:
        """Correspondences needed before computing (a parameter may raise the bound)."""
        return self.MIN_CORRESPONDENCES

    def progress(self) -> dict[str, Progress]:
        """For a static output estimated over time (a calibration): its progress by output port
        (``instance`` left empty: the worker fills it in); none by default."""
        return {}


def complete_correspondences(values: Inputs, ports: tuple[str, ...]) -> list[tuple]:
    """Rows of the aligned correspondence lists in which every port has a value."""
    rows = zip(*(values[port] for port in ports), strict=True)
    return [row for row in rows if all(value is not None for value in row)]


SERVICES: dict[str, type[Service]] = {}


def register(cls: type[Service]) -> type[Service]:
    """Class decorator adding a service to :data:`SERVICES` under its ``NAME``."""
    if cls.NAME in SERVICES:
        raise ValueError(f"service {cls.NAME!r} registered twice")
    SERVICES[cls.NAME] = cls
    return cls


def lookup(name: str) -> type[Service]:
    """The registered service called ``name``; ``KeyError`` with the known names otherwise."""
    load_components()
    try:
        return SERVICES[name]
    except KeyError:
        raise KeyError(f"no registered service {name!r}; known: {sorted(SERVICES)}") from None


@functools.cache
def load_components() -> None:
    """Import every module of :mod:`ubitrack_agent.services.components` (found by
    :func:`pkgutil.iter_modules`, no list to keep); each registers its services on import."""
    from ubitrack_agent.services import components

    for module in pkgutil.iter_modules(components.__path__, f"{components.__name__}."):
        importlib.import_module(module.name)
