"""Progress of a static relation computed from dynamic inputs: the calibration's state on the
wire.

A worker whose output is a static estimate (averaging a calibration over time, section 4.2 of
the paper) publishes, beside each new estimate on the relation key, a :class:`Progress` on
``<root>/progress/<from>/<to>/<type>/static`` (``.../recalibrate`` for a recalibration;
``KeySpace.progress``): where the estimate stands, how many samples it holds and rejected, how
uncertain it is against the tolerances it must reach, and the estimate itself. Applications
(``Relation.progress``), ``ubitrack calibrate`` and the calibration store read it; JSON, one
object::

    {"instance": "averaging-1a2b3c", "status": "averaging", "accepted": 212, "rejected": 3,
     "std_translation": 0.0011, "std_rotation": 0.0009, "tolerance_translation": 0.001,
     "tolerance_rotation": 0.0017, "spread_translation": 0.004, "spread_rotation": 0.003,
     "noise_scale": 1.1, "motion": null, "timestamp_ns": 1795356121000000000,
     "value": {"type": "ErrorPose", "rotation": [...], "translation": [...], "covariance": [...]}}

``status`` is one of :data:`STATUSES`: ``initialising`` (too few samples for an estimate),
``averaging``, ``converged`` (the documented rule of
``ubitrack_agent.services.algorithms.static_estimate``: final, the flow may stop) or ``not_static``
(the inputs move more than their noise explains: the relation is not static and nothing is averaged;
``motion`` says how far it moved). Lengths in metres, angles in radians. :func:`parse_progress` is
total: it returns a :class:`Progress` or raises :class:`ProgressError`.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from typing import Any

from ubitrack_agent.net.json_messages import MessageError, field, load_object
from ubitrack_agent.net.keys import validate_key_chunks

STATUSES = ("initialising", "averaging", "converged", "not_static")
MAX_PROGRESS_BYTES = 64 * 1024
"""A progress message holds one estimate: a few kilobytes."""

_NUMBERS = (
    "std_translation",
    "std_rotation",
    "tolerance_translation",
    "tolerance_rotation",
    "spread_translation",
    "spread_rotation",
    "noise_scale",
)


class ProgressError(ValueError):
    """A progress message that breaks its form; the message names the field."""


@dataclass(frozen=True)
class Progress:
    """The state of one static estimate (see the module docstring)."""

    instance: str
    status: str
    accepted: int
    rejected: int
    timestamp_ns: int
    std_translation: float | None = None
    std_rotation: float | None = None
    tolerance_translation: float | None = None
    tolerance_rotation: float | None = None
    spread_translation: float | None = None
    spread_rotation: float | None = None
    noise_scale: float | None = None
    motion: dict[str, Any] | None = None
    value: dict[str, Any] | None = None
    """The estimate in ``core.to_json`` form (type tag, fields as lists), or None."""

    @property
    def converged(self) -> bool:
        return self.status == "converged"

    @property
    def not_static(self) -> bool:
        return self.status == "not_static"

    def fraction_done(self) -> float:
        """How close the estimate is to its tolerances, 0..1 (1 when converged): the smaller
        of tolerance / standard deviation over translation and rotation (a standard deviation
        falls as 1/sqrt(samples), so this rises as sqrt(samples))."""
        if self.converged:
            return 1.0
        ratios = [
            min(1.0, tolerance / std)
            for std, tolerance in (
                (self.std_translation, self.tolerance_translation),
                (self.std_rotation, self.tolerance_rotation),
            )
            if std is not None and tolerance is not None and std > 0
        ]
        return min(ratios) if ratios else 0.0

    def to_json(self) -> str:
        return json.dumps(asdict(self))


def parse_progress(payload: bytes | None) -> Progress:
    """The :class:`Progress` in ``payload``, or :class:`ProgressError` naming what is wrong."""
    try:
        data = load_object(payload, MAX_PROGRESS_BYTES)
        unknown = sorted(set(data) - {f for f in Progress.__dataclass_fields__})
        if unknown:
            raise ProgressError(f"unknown fields {unknown}")
        status = field(data, "status", str)
        if status not in STATUSES:
            raise ProgressError(f"status: expected one of {STATUSES}, got {status!r}")
        counts = {name: field(data, name, int) for name in ("accepted", "rejected")}
        timestamp = field(data, "timestamp_ns", int)
        if min(*counts.values(), timestamp) < 0 or timestamp >= 2**63:
            raise ProgressError("accepted, rejected and timestamp_ns must be in [0, 2^63)")
        numbers = {name: field(data, name, float, optional=True) for name in _NUMBERS}
        motion = field(data, "motion", dict, optional=True)
        value = field(data, "value", dict, optional=True)
        instance = validate_key_chunks(field(data, "instance", str), single_chunk=True)
    except (MessageError, ValueError) as exc:
        raise ProgressError(f"progress: {exc}") from None
    return Progress(
        instance, status, **counts, timestamp_ns=timestamp, **numbers, motion=motion, value=value
    )
