"""Calibrating a static relation live, as an application does it: follow the estimate's
progress until it converges, then keep the result in a calibration store.

:func:`follow` watches a static :class:`~ubitrack_agent.io.application.Relation` and reports
its progress (``ubitrack_agent.net.progress``) at most every ``report_every_s`` and on each
change of status; it ends with an :class:`Outcome`: ``converged`` (the estimator's rule),
``known`` (a value arrives but no progress: the relation is a measured static edge, e.g. one
stored earlier), ``not_static`` or ``timeout``; unless the relation keeps waiting, it raises at
once what the agent's answer makes pointless to wait for (``Relation.verdict``:
``UnsolvedRelation``, ``NoAgent``). :func:`save` sends a converged result to the
calibration store (``docs/protocol.md``, "Calibration"). ``ubitrack calibrate`` and the demo
use both. Following a recalibration (a ``Relation`` of a ``RelationId(..., recalibrate=True)``)
is the same; saving its result replaces the stored value, the previous one going to the
entry's history.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ubitrack_agent.core import to_json
from ubitrack_agent.io.application import NotStatic, Relation
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.progress import Progress

KNOWN_AFTER_S = 2.0
"""A value that has arrived while no progress report came for this long is not being
calibrated: it is a measured static edge (a stored calibration), or a flow the agent replaced
by one."""


@dataclass(frozen=True)
class Outcome:
    """How following a calibration ended (see the module docstring)."""

    kind: str
    """``converged``, ``known``, ``not_static`` or ``timeout``."""
    progress: Progress | None
    value: dict[str, Any] | None
    """The relation's value in ``core.to_json`` form (converged or known), else None."""


class StoreError(RuntimeError):
    """The calibration store refused a save request or did not answer."""


def _waited(since: float | None, seconds: float) -> bool:
    return since is not None and time.monotonic() - since > seconds


def follow(
    relation: Relation,
    timeout: float,
    report: Callable[[Progress], None],
    report_every_s: float = 0.5,
) -> Outcome:
    """Follow the static ``relation`` until one of the outcomes (see the module docstring);
    ``UnsolvedRelation`` or ``NoAgent`` as soon as :meth:`Relation.verdict` has one."""
    deadline = time.monotonic() + timeout
    reported, reported_at, value_at = None, 0.0, None
    while time.monotonic() < deadline:
        try:
            relation.wait_for(timeout=0.5)
        except NotStatic as exc:
            return Outcome("not_static", exc.progress, None)
        except TimeoutError:
            if (verdict := relation.verdict()) is not None:
                raise verdict from None
        progress = relation.progress
        if value_at is None and relation.latest() is not None:
            value_at = time.monotonic()
        live = progress is not None and not _waited(relation.progress_at, KNOWN_AFTER_S)
        if live and (progress.status != reported or _waited(reported_at, report_every_s)):
            reported, reported_at = progress.status, time.monotonic()
            report(progress)
            if progress.converged:
                return Outcome("converged", progress, progress.value)
        elif not live and _waited(value_at, KNOWN_AFTER_S):
            return Outcome("known", None, to_json(relation.latest()))
    return Outcome("timeout", relation.progress, None)


def save_request(source: str, target: str, edge_type: str, progress: Progress) -> dict[str, Any]:
    """The save request for a converged ``progress`` (its value and provenance)."""
    value = {k: v for k, v in (progress.value or {}).items() if k not in ("type", "timestamp_ns")}
    return {
        "from": source,
        "to": target,
        "type": edge_type,
        "value": value,
        "provenance": {
            "time": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "flow": progress.instance,
            "samples": progress.accepted,
            "rejected": progress.rejected,
            "std_translation": progress.std_translation,
            "std_rotation": progress.std_rotation,
        },
    }


def save(session: Any, keys: KeySpace, store: str, request: dict[str, Any]) -> dict[str, Any]:
    """Send ``request`` to the store ``store``; its answer (``file``, ``edge``, ``provider``),
    or :class:`StoreError` saying why not."""
    for reply in session.get(keys.store(store), payload=json.dumps(request), timeout=5.0):
        if reply.ok is not None:
            return json.loads(reply.ok.payload.to_bytes())
        raise StoreError(f"the store refused: {reply.err.payload.to_bytes().decode()}")
    raise StoreError(
        f"no calibration store answers on {keys.store(store)}; start one with `ubitrack store FILE`"
    )
