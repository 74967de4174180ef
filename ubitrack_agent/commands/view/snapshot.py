"""What the live view shows, built from what the network says: the agent's status (a JSON
object, read as untrusted input), each component enriched with its pattern, counters and
measured output rate, and the relations worth watching. Pure: the zenoh side is
:mod:`ubitrack_agent.commands.view.watch`."""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from ubitrack_agent.graph.templates import Template
from ubitrack_agent.net.keys import KeySpace, RelationId

MAX_RELATIONS = 64
"""Most relations the view watches (one subscriber each), whatever a status lists."""


class StatusError(ValueError):
    """A status payload that is not a JSON object."""


@dataclass(frozen=True)
class Snapshot:
    """Everything the pages show, as of ``taken_ns`` (wall clock)."""

    taken_ns: int
    status: dict[str, Any] | None
    """The agent's status, enriched (:func:`enrich`); None when there is none to show."""
    problem: str | None = None
    """Why there is no status: no agent answers, or its answer is malformed."""
    rates: dict[str, float] = field(default_factory=dict)
    """Each component's measured output rate (Hz), by instance."""
    relations: dict[str, dict[str, Any]] = field(default_factory=dict)
    """A row per queried or watched relation (:func:`relation_rows`), by query name."""
    counters: dict[str, int] = field(default_factory=dict)
    """The view's own problems: undecodable samples, failed polls."""


def parse_status(payload: bytes) -> dict[str, Any]:
    """The agent's status from its reply; :class:`StatusError` when it is no JSON object, or
    holds a number JSON cannot carry (``NaN``, ``Infinity``, ``1e999``: the browser's
    ``JSON.parse`` would refuse the view's answer)."""
    try:
        status = json.loads(payload, parse_constant=_non_finite, parse_float=_finite)
    except (ValueError, RecursionError) as exc:  # not UTF-8 or JSON; nested too deep
        raise StatusError(f"the agent's status is not JSON: {str(exc)[:200]}") from None
    if not isinstance(status, dict):
        raise StatusError(f"the agent's status is not a JSON object but {type(status).__name__}")
    return status


def _non_finite(text: str) -> float:
    raise ValueError(f"{text} is not a JSON number")


def _finite(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"{text[:40]} is out of range")
    return value


def pattern_names(templates: Iterable[Template]) -> dict[str, str]:
    """The pattern each service implements (``fusion`` -> ``MultiTrackerFusion``)."""
    return {template.service: template.pattern for template in templates}


def enrich(
    status: dict[str, Any],
    counters: Mapping[str, Mapping[str, Any]],
    rates: Mapping[str, float],
    patterns: Mapping[str, str],
    latencies: Mapping[str, Mapping[str, float]] | None = None,
) -> dict[str, Any]:
    """A copy of ``status`` whose components also carry their worker's ``counters`` and its
    inputs' ``latency_ms`` (as ``ubitrack status --json`` shows them; the data flow's wires
    show the latency), their ``pattern`` (the service's, where a template names one) and
    their measured output rate ``rate_hz`` (None before it is measured).
    Components that are not JSON objects are left as they are; of a worker's counters, only
    integers are shown (they come from the network too)."""
    components = status.get("components")
    if not isinstance(components, dict):
        return dict(status)
    enriched = {}
    for instance, component in components.items():
        if isinstance(component, dict):
            service = component.get("service")
            component = {
                **component,
                "counters": _integers(counters.get(instance)),
                "pattern": patterns.get(service) if isinstance(service, str) else None,
                "rate_hz": rates.get(instance),
                "latency_ms": dict((latencies or {}).get(instance, {})),
            }
        enriched[instance] = component
    return {**status, "components": enriched}


def _integers(counters: Mapping[str, Any] | None) -> dict[str, int] | None:
    if counters is None:
        return None
    return {name: value for name, value in counters.items() if _count(value)}


def output_rates(
    before: Mapping[str, Mapping[str, Any]], after: Mapping[str, Mapping[str, Any]], seconds: float
) -> dict[str, float]:
    """Each worker's published samples per second between two readings of the counters
    ``seconds`` apart, for the workers in both whose ``published`` counts are integers."""
    rates = {}
    for instance, counters in after.items():
        published = counters.get("published")
        earlier = before.get(instance, {}).get("published")
        if _count(published) and _count(earlier) and seconds > 0:
            rates[instance] = max(published - earlier, 0) / seconds
    return rates


def _count(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def watched_relations(status: Mapping[str, Any], keys: KeySpace) -> dict[str, RelationId]:
    """The relations ``status`` says are served, by name, whose keys are relation keys of this
    view's root (a key outside it, or malformed, is left out: the view only subscribes to keys
    it builds itself); at most :data:`MAX_RELATIONS`."""
    served = status.get("relations")
    if not isinstance(served, dict):
        return {}
    watched: dict[str, RelationId] = {}
    for name, entry in served.items():
        key = entry.get("key") if isinstance(entry, dict) else None
        if not isinstance(key, str) or len(watched) >= MAX_RELATIONS:
            continue
        try:
            relation = keys.parse_relation(key)
        except ValueError:
            continue
        watched[name] = relation
    return watched


def relation_rows(
    status: Mapping[str, Any], series: Mapping[str, dict[str, Any]]
) -> dict[str, dict[str, Any]]:
    """A row per queried relation, by the name the status gives it (``C->A:6D``,
    ``C->HT:6D/static``, as :func:`watched_relations` names them): its
    ``applications``, the ``hosts`` they run on, why it is ``unsolved`` (None if it is not,
    or not known) and its ``series`` (None if it is not watched). Relations watched but no
    longer in the status's queries (no agent answers) keep their rows."""
    queries = _mapping(status.get("queries"))
    hosts = _mapping(status.get("application_hosts"))
    unsolved = {name: str(why) for name, why in _mapping(status.get("unsolved")).items()}
    return {
        name: {
            "applications": _strings(queries.get(name)),
            "hosts": _strings(hosts.get(name)),
            "unsolved": unsolved.get(name),
            "series": series.get(name),
        }
        for name in sorted({*queries, *unsolved, *series})
    }


def _mapping(value: Any) -> Mapping[str, Any]:
    return value if isinstance(value, dict) else {}


def _strings(value: Any) -> list[str]:
    return [item for item in value if isinstance(item, str)] if isinstance(value, list) else []
