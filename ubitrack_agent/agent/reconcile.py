"""What turns the running workers into the wanted ones: start, stop, or update in place.

Specifications are compared field by field. Inputs, relation routes and parameters can change
in a running worker (a control command, ``ubitrack_agent.services.worker``); a change of service,
output keys, expansion or timing options needs a new one (output keys never change in practice: the
agent names each output after its component, ``agent.materialise``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ubitrack_agent.net.spec import ComponentSpec

IN_PLACE = ("inputs", "relations", "parameters")


@dataclass(frozen=True)
class Actions:
    start: tuple[ComponentSpec, ...] = ()
    stop: tuple[str, ...] = ()
    update: tuple[tuple[str, dict[str, Any]], ...] = ()
    """(instance, control command) pairs."""

    @property
    def empty(self) -> bool:
        return not (self.start or self.stop or self.update)


def control_command(old: ComponentSpec, new: ComponentSpec) -> dict[str, Any] | None:
    """The control command making ``old`` into ``new`` in place; None if a restart is needed."""
    if _without_in_place(old) != _without_in_place(new):
        return None
    command: dict[str, Any] = {}
    wire = new.as_dict()
    for field_name in IN_PLACE:
        if getattr(old, field_name) != getattr(new, field_name):
            command[field_name] = wire[field_name]
    return command


def _without_in_place(spec: ComponentSpec) -> dict[str, Any]:
    data = spec.as_dict()
    for field_name in IN_PLACE:
        data.pop(field_name)
    return data


def reconcile(running: Mapping[str, ComponentSpec], wanted: Mapping[str, ComponentSpec]) -> Actions:
    """Actions from the ``running`` specifications to the ``wanted`` ones."""
    start = [spec for instance, spec in wanted.items() if instance not in running]
    stop = [instance for instance in running if instance not in wanted]
    update = []
    for instance, spec in wanted.items():
        old = running.get(instance)
        if old is None or old == spec:
            continue
        command = control_command(old, spec)
        if command is None:
            stop.append(instance)
            start.append(spec)
        else:
            update.append((instance, command))
    return Actions(tuple(start), tuple(stop), tuple(update))
