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

from services.registry import Service, lookup
from ubitrack_agent.net.spec import (
    ComponentSpec,
    InputBinding,
    SpecError,
    parse_before_port,
    parse_then_port,
)


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
    correspondence port under space expansion). A binding of a static edge an output is
    composed with (``net.spec.then_port``) names an output, is static and does not trigger;
    an output's are numbered from 0 in turn. So are the static edges an ``inverted`` input's
    samples are composed with (``net.spec.before_port``), which name that input by its index;
    an inverted input is dynamic and its port takes what an inversion gives."""
    composed: dict[object, list[int]] = {}
    for index, binding in enumerate(bindings):
        then = parse_then_port(binding.port)
        before = parse_before_port(binding.port)
        edge = then is not None or before is not None
        if edge and (not binding.static or binding.trigger or binding.inverted):
            raise SpecError(
                f"{where}[{index}]: a composed edge is static and no trigger, not inverted"
            )
        if then is not None:
            output, order, _ = then
            if output not in service.OUTPUTS:
                raise SpecError(f"{where}[{index}].port: {service.NAME} has no output {output!r}")
            composed.setdefault(output, []).append(order)
        elif before is not None:
            target, order, _ = before
            if not (target < len(bindings) and bindings[target].inverted):
                raise SpecError(f"{where}[{index}].port: input {target} is no inverted input")
            composed.setdefault(target, []).append(order)
        elif binding.port not in service.INPUTS:
            raise SpecError(f"{where}[{index}].port: {service.NAME} has no input {binding.port!r}")
        elif binding.inverted:
            if binding.static:
                raise SpecError(f"{where}[{index}]: an inverted input is dynamic")
            if not inverted_types(service.INPUTS[binding.port].types):
                raise SpecError(
                    f"{where}[{index}]: port {binding.port!r} takes nothing an inversion gives"
                )
    for target, orders in composed.items():
        if sorted(orders) != list(range(len(orders))):
            raise SpecError(f"{where}: the edges composed with {target!r} are not numbered 0..n")
    for port in service.INPUTS:
        count = sum(binding.port == port for binding in bindings)
        listed = expansion == "space" and port in service.CORRESPONDENCE
        if count == 0 or (count > 1 and not listed):
            needed = "one or more bindings" if listed else "exactly one binding"
            raise SpecError(f"{where}: port {port!r} needs {needed}, got {count}")


def inverted_types(types: tuple[type, ...]) -> tuple[type, ...]:
    """Of the measurement types a port takes, those an inverted input of it reads: the ones
    the inversion service takes (it gives the same type back)."""
    invertible = lookup("inversion").INPUTS["AB"].types
    return tuple(kind for kind in types if kind in invertible)


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
