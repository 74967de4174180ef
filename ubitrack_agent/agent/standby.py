"""Derivations kept beside the new one when a sensor is lost: a sensor that comes back within
``STANDBY_S`` (an occluded body seen again, a tracker restarted) is used again at its first
measurement, without waiting for the agent (issue [seamless], "make before break").

When an edge vanishes (its provider left, or it went quiet: ``agent.liveness``) the agent plans
the relations it served again and starts the new derivation beside the old one. The old one
would be stopped once the new one has taken the relation's key over (``agent.runtime``,
``_retire``). Instead, the old derivation of a relation that read a lost edge is kept running,
its components still subscribed to the lost edge's data key: a fusion goes on with the inputs
it still has, and its producer keeps the key until the new flow is as certain, then keeps
watching it. When the lost edge's data flows again, the producer takes the key back itself
within a sample (``services.handover``, rule 6: an input back, and no less certain than the
holder), if it gave it away. The agent then sees the edge again, plans the same derivation
as before (the same component ids: ``graph.dataflow.from_solution``), adopts the standby
components instead of starting them, and retires the other flow.

A standby costs the CPU of its components for at most ``STANDBY_S``. Finding one costs, per
reconfiguration that retires components, O(edges) for the live data keys, a pass building the
producer of each data key, and a walk upstream from each retired relation producer:
O(edges + retired producers x (components + inputs)).
"""

from __future__ import annotations

from collections.abc import Collection, Iterable, Mapping

from ubitrack_agent.net.spec import ComponentSpec


def standby_components(
    running: Mapping[str, ComponentSpec],
    retired: Iterable[str],
    live_keys: Collection[str],
) -> set[str]:
    """The ``retired`` components (instances of ``running``, the specifications before the
    change) to keep on standby: those of the derivation of a relation whose producer is
    retired (its upstream components, through the data keys workers produce) that reads a
    measured edge's data key no longer in ``live_keys`` (the data keys of the live SRG's
    measured edges). Every other retired component is stopped as before."""
    retired = set(retired)
    producer_of = {
        key: instance for instance, spec in running.items() for key in spec.outputs.values()
    }
    keep: set[str] = set()
    for instance in sorted(retired):
        if not running[instance].relations:
            continue  # not a relation's producer: kept only as part of one's derivation
        derivation = _upstream(instance, running, producer_of)
        lost = any(
            not binding.from_worker and binding.key not in live_keys
            for member in derivation
            for binding in running[member].inputs
        )
        if lost:
            keep |= derivation & retired
    return keep


def _upstream(
    instance: str, running: Mapping[str, ComponentSpec], producer_of: Mapping[str, str]
) -> set[str]:
    """``instance`` and every running component it reads from, directly or not."""
    seen, todo = {instance}, [instance]
    while todo:
        for binding in running[todo.pop()].inputs:
            source = producer_of.get(binding.key)
            if source is not None and source not in seen:
                seen.add(source)
                todo.append(source)
    return seen
