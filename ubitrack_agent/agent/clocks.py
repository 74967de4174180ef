"""Which inputs of which components need their timestamps moved to the agent's clock, and by
how much (``docs/protocol.md``, "Clocks").

Measurements are stamped on their sensor host's clock; each host manager estimates its host's
offset to the agent's clock (``net.clock``, ``ubitrack_agent.services.clock_sync``). A *clock
domain* is the clock a stream's timestamps are on: a measured edge's is its provider's host; a
component's outputs are on the agent's clock (:data:`REFERENCE`) if its inputs were corrected, else
on the clock of its inputs (of its first triggering one when they differ within its tolerance, as a
synchronised output takes its trigger's time). Static inputs answer their value at any time,
so their clock does not matter.

A component whose dynamic inputs come from clock domains whose offsets differ by more than its
tolerance (``ComponentSpec.tolerance_ms``, the synchronisation window) gets on each such input
``clock_offset_ns``, the offset of that input's domain to the agent's clock, which the worker
adds to every sample (``ubitrack_agent.services.worker``). What cannot be done well is reported per
component:

* a domain without an estimate (a host whose host manager has not measured yet, or runs none,
  or an edge whose host is not known): the inputs are left as they are;
* estimates too uncertain: corrected, but two inputs may still be apart by the sum of their
  domains' uncertainties, more than the tolerance;
* a domain whose clock reads more than ``core.measurements.MAX_FUTURE_NS`` ahead of the clock of
  the host the component runs on (``placement``): the worker refuses its samples as stamped in
  the future, before any correction.

Offsets follow the estimates, but an input keeps the offset it had in ``previous`` while the
new estimate is within its uncertainty of it, so a refreshed estimate does not rewire every
corrected worker. Pure: no zenoh, no clock read.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from itertools import combinations

from ubitrack_agent.core.measurements import MAX_FUTURE_NS
from ubitrack_agent.net.clock import ClockEstimate
from ubitrack_agent.net.config import MAX_CLOCK_OFFSET_NS
from ubitrack_agent.net.spec import ComponentSpec, InputBinding

REFERENCE = "<agent>"
"""The clock domain of the agent's clock (never a host name: ``<`` breaks the name rule)."""
EXACT = ClockEstimate(0, 0, 0, 1)
"""The agent's clock against itself."""

Domain = str | None
"""A host name, :data:`REFERENCE`, or None: a clock not known."""


def correct_clocks(
    specs: Mapping[str, ComponentSpec],
    data_hosts: Mapping[str, str],
    placement: Mapping[str, str],
    estimates: Mapping[str, ClockEstimate | None],
    previous: Mapping[str, ComponentSpec] | None = None,
) -> tuple[dict[str, ComponentSpec], dict[str, str]]:
    """``specs`` (instance -> specification) with ``clock_offset_ns`` set where needed, and
    the reason for each component whose clocks cannot be aligned within its tolerance (module
    docstring). ``data_hosts`` maps measured edges' data keys to their provider's host,
    ``placement`` instances to the host they run on, ``estimates`` hosts to their clock's
    offset to the agent's (None: not measured yet); ``previous`` is the specifications sent
    before. Inputs are read from the producers' outputs in any order."""
    return _Corrector(specs, data_hosts, placement, estimates, previous or {}).run()


class _Corrector:
    """One run of :func:`correct_clocks`."""

    def __init__(
        self,
        specs: Mapping[str, ComponentSpec],
        data_hosts: Mapping[str, str],
        placement: Mapping[str, str],
        estimates: Mapping[str, ClockEstimate | None],
        previous: Mapping[str, ComponentSpec],
    ) -> None:
        self.specs, self.data_hosts, self.placement = specs, data_hosts, placement
        self.estimates, self.previous = estimates, previous
        self.producers = {
            key: instance
            for instance, spec in specs.items()
            for key in (*spec.outputs.values(), *(k for ks in spec.relations.values() for k in ks))
        }
        self.corrected: dict[str, ComponentSpec] = {}
        self.domains: dict[str, Domain] = {}
        self.reasons: dict[str, list[str]] = {}
        self._resolving: set[str] = set()

    def run(self) -> tuple[dict[str, ComponentSpec], dict[str, str]]:
        for instance in self.specs:
            self._domain_of(instance)
        reasons = {instance: "; ".join(texts) for instance, texts in self.reasons.items()}
        return {instance: self.corrected[instance] for instance in self.specs}, reasons

    def _estimate(self, domain: Domain) -> ClockEstimate | None:
        if domain == REFERENCE:
            return EXACT
        estimate = None if domain is None else self.estimates.get(domain)
        if estimate is None or abs(estimate.offset_ns) > MAX_CLOCK_OFFSET_NS:
            return None
        return estimate

    def _key_domain(self, key: str) -> Domain:
        if key in self.data_hosts:
            return self.data_hosts[key]
        producer = self.producers.get(key)
        return None if producer is None else self._domain_of(producer)

    def _domain_of(self, instance: str) -> Domain:
        """The clock domain of ``instance``'s outputs, deciding its corrections on the way."""
        if instance in self.domains:
            return self.domains[instance]
        if instance in self._resolving:
            return None  # a loop of components: no clock can be told
        self._resolving.add(instance)
        spec = self.specs[instance]
        dynamic = [binding for binding in spec.inputs if not binding.static]
        domains = {binding: self._key_domain(binding.key) for binding in dynamic}
        self.domains[instance] = self._decide(instance, spec, domains)
        self._resolving.discard(instance)
        self._check_ahead(instance, set(domains.values()))
        return self.domains[instance]

    def _decide(
        self, instance: str, spec: ComponentSpec, domains: dict[InputBinding, Domain]
    ) -> Domain:
        """Correct ``instance``'s inputs if their clocks differ by more than its tolerance;
        the domain of its outputs."""
        self.corrected[instance] = spec
        distinct = set(domains.values())
        if len(distinct) <= 1:
            return next(iter(distinct), None)
        shown = ", ".join(sorted(_name(domain) for domain in distinct))
        estimates = {domain: self._estimate(domain) for domain in distinct}
        missing = sorted(_name(d) for d, estimate in estimates.items() if estimate is None)
        if missing:
            self._report(
                instance,
                f"inputs on the clocks of {shown}: no usable clock offset for "
                f"{', '.join(missing)} to align them",
            )
            return None
        known = {d: estimate for d, estimate in estimates.items() if estimate is not None}
        offsets = [estimate.offset_ns for estimate in known.values()]
        if max(offsets) - min(offsets) <= spec.tolerance_ns:
            triggers = [binding for binding in domains if binding.trigger] or list(domains)
            return domains[triggers[0]]
        self.corrected[instance] = replace(
            spec, inputs=tuple(self._offset(instance, b, domains, known) for b in spec.inputs)
        )
        worst = max(a.uncertainty_ns + b.uncertainty_ns for a, b in combinations(known.values(), 2))
        if worst > spec.tolerance_ns:
            self._report(
                instance,
                f"inputs on the clocks of {shown} corrected, but may still be "
                f"{worst / 1e6:.3f} ms apart (the clock offsets' uncertainty), more than the "
                f"tolerance of {spec.tolerance_ms:g} ms",
            )
        return REFERENCE

    def _offset(
        self,
        instance: str,
        binding: InputBinding,
        domains: dict[InputBinding, Domain],
        known: dict[Domain, ClockEstimate],
    ) -> InputBinding:
        """``binding`` with the offset of its domain to the agent's clock (or the one it had,
        if still within the estimate's uncertainty)."""
        if binding not in domains:
            return binding  # a static input
        estimate = known[domains[binding]]
        offset = estimate.offset_ns
        before = self.previous.get(instance)
        for old in before.inputs if before is not None else ():
            same = (old.port, old.key, old.static) == (binding.port, binding.key, binding.static)
            if same and abs(old.clock_offset_ns - offset) <= estimate.uncertainty_ns:
                offset = old.clock_offset_ns
        return replace(binding, clock_offset_ns=offset)

    def _check_ahead(self, instance: str, domains: set[Domain]) -> None:
        """Report input clocks so far ahead of the clock where ``instance`` runs that the
        worker refuses their samples (``core.measurements.MAX_FUTURE_NS``)."""
        host = self.placement.get(instance)
        runs_on = self._estimate(host)
        if runs_on is None:
            return
        for domain in sorted(domains - {None}):
            estimate = self._estimate(domain)
            ahead_ns = None if estimate is None else runs_on.offset_ns - estimate.offset_ns
            if ahead_ns is not None and ahead_ns > MAX_FUTURE_NS:
                self._report(
                    instance,
                    f"the clock of {_name(domain)} reads {ahead_ns / 1e9:.1f} s ahead of that "
                    f"of host {host}, where it runs: its samples are refused as stamped ahead",
                )

    def _report(self, instance: str, reason: str) -> None:
        self.reasons.setdefault(instance, []).append(reason)


def _name(domain: Domain) -> str:
    if domain == REFERENCE:
        return "the agent"
    return "an unknown host" if domain is None else f"host {domain}"
