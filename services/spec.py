"""A component specification checked against the registered service it names.

:func:`ubitrack_agent.net.spec.parse_spec` checks a specification's form; this module checks
what only the services know: the service is registered, the bindings fit its input ports and
the correspondence's expansion, the outputs and relation routes name its output ports, the
service accepts the parameters. The worker (and an idle pool worker) and the host manager run
both checks before anything starts, so nothing from the network runs but a registered service
wired as it declares.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ubitrack_agent.net.spec import ComponentSpec, InputBinding, SpecError
from ubitrack_agent.services.registry import Service, lookup


def check_spec(spec: ComponentSpec) -> type[Service]:
    """The registered service of ``spec``, or :class:`SpecError` naming the field."""
    try:
        service = lookup(spec.service)
    except KeyError as exc:
        raise SpecError(f"spec.service: {exc.args[0]}") from None
    check_outputs(spec.outputs, service)
    if spec.expansion != "none" and not service.CORRESPONDENCE:
        raise SpecError(f"spec.expansion: {service.NAME} has no correspondence to expand")
    check_bindings(spec.inputs, service, spec.expansion)
    check_relations(spec.relations, service)
    check_parameters(spec.parameters, service)
    return service


def check_parameters(parameters: Mapping[str, Any], service: type[Service]) -> Service:
    """The service built with ``parameters``, or :class:`SpecError` if it refuses them (unknown
    names, wrong types, values out of range or overflowing)."""
    try:
        return service(parameters)
    except (ValueError, TypeError, ArithmeticError) as exc:
        raise SpecError(f"spec.parameters: {exc}") from None


def check_bindings(
    bindings: tuple[InputBinding, ...],
    service: type[Service],
    expansion: str,
    where: str = "spec.inputs",
) -> None:
    """Every binding names an input port; every port has one binding (several for a
    correspondence port under space expansion)."""
    for index, binding in enumerate(bindings):
        if binding.port not in service.INPUTS:
            raise SpecError(f"{where}[{index}].port: {service.NAME} has no input {binding.port!r}")
    for port in service.INPUTS:
        count = sum(binding.port == port for binding in bindings)
        listed = expansion == "space" and port in service.CORRESPONDENCE
        if count == 0 or (count > 1 and not listed):
            needed = "one or more bindings" if listed else "exactly one binding"
            raise SpecError(f"{where}: port {port!r} needs {needed}, got {count}")


def check_outputs(
    outputs: Mapping[str, str], service: type[Service], where: str = "spec.outputs"
) -> None:
    """Every output key is that of an output port of ``service``."""
    for port in outputs:
        if port not in service.OUTPUTS:
            raise SpecError(f"{where}: {service.NAME} has no output {port!r}")


def check_relations(
    relations: Mapping[str, tuple[str, ...]],
    service: type[Service],
    where: str = "spec.relations",
) -> None:
    """Every relation route leaves from an output port of ``service``."""
    for port in relations:
        if port not in service.OUTPUTS:
            raise SpecError(f"{where}: {service.NAME} has no output {port!r}")
