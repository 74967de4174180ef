"""Planning off the agent's loop: one planning thread, fed snapshots, whose outdated results are
never applied.

The agent's loop keeps answering (status, answers, liveliness, host reports) while a plan is
made: it hands a :class:`Request` (an immutable snapshot of what planning reads: the accepted
fragments, the stale edges, the queried relations, the running components, a generation
number) to :class:`BackgroundPlanner`'s thread, which builds the live SRG, replans incrementally
(:mod:`.replanning`) and turns a changed plan into worker specifications
(``agent.materialise``), all pure. The loop takes the :class:`Outcome` when it is ready and
applies it only if no event changed the agent's state since the snapshot (its generation is
still the current one); an outdated outcome is dropped, and the next request, made from the
newest state, replans incrementally from it (its SRG and parts are a plan as good as any to
compare with), so events that keep coming never starve planning and none is lost: each event
bumps the generation, and a request is made whenever the applied generation is behind.

The thread holds Python's interpreter lock while it plans, but the interpreter hands it over
every few milliseconds (``sys.getswitchinterval``, 5 ms), so the loop is held up at most that
long per switch, however long the plan takes.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from ubitrack_agent.agent.flows import Planner
from ubitrack_agent.agent.live_srg import LiveSrg, live_srg
from ubitrack_agent.agent.materialise import Keys, component_specs
from ubitrack_agent.agent.replanning import Planned, replan
from ubitrack_agent.agent.spares import DEFAULT_REDUNDANCY, Redundancy
from ubitrack_agent.graph.dataflow import DataFlow
from ubitrack_agent.graph.planner import plan
from ubitrack_agent.graph.templates import Template
from ubitrack_agent.net.keys import RelationId
from ubitrack_agent.net.spec import ComponentSpec


@dataclass(frozen=True)
class Request:
    """A snapshot of what planning reads, taken on the agent's loop (``generation``: the number
    of state changes seen when it was taken)."""

    generation: int
    fragments: Mapping[str, list[dict[str, Any]]]
    stale: frozenset[str]
    relations: frozenset[RelationId]
    running: frozenset[str]
    follow: bool
    """Whether choices follow the previous plan's derivations (the active agent)."""
    appeared: frozenset[str] = frozenset()
    """The workers nothing ran that appeared since the last plan applied (the relations they
    may serve are planned again: ``agent.replanning``)."""
    taken_ns: int = 0
    """When the snapshot was taken (``time.time_ns``: ``agent.stamps``)."""


@dataclass(frozen=True)
class Outcome:
    """A plan made from ``request``: the live SRG and the planning state, and the worker
    specifications of its plan (``labels``: the host labels each component's template
    requires; ``isolated``: the components whose template asks for a container of their own,
    ``Template.isolation``), the host of each measured edge by data key, and how long it took
    (all of it, and replanning)."""

    request: Request
    live: LiveSrg
    planned: Planned
    wanted: Mapping[str, ComponentSpec]
    labels: Mapping[str, frozenset[str]]
    isolated: frozenset[str]
    data_hosts: Mapping[str, str]
    seconds: float
    replanning_s: float = 0.0
    """Of ``seconds``, the time :func:`.replanning.replan` took (the rest: the SRG and the
    specifications)."""
    made_ns: int = 0
    """When it was finished (``time.time_ns``: ``agent.stamps``)."""


def make_outcome(
    request: Request,
    previous: Outcome | None,
    templates: Sequence[Template],
    keys: Keys,
    planner: Planner = plan,
    redundancy: Redundancy = DEFAULT_REDUNDANCY,
) -> Outcome:
    """Plan ``request`` incrementally from ``previous``, each relation with ``planner`` (pure
    but for a memo's contents: ``agent.plan_memo``). The specifications are made again only
    when the plan changed. O(edges) for the SRG (``agent.live_srg``: no fragment parsed
    again), plus :func:`.replanning.replan`'s cost, plus O(components + bindings) when the
    plan changed (``materialise.component_specs``). ``redundancy``: the spares and replicas
    each derivation gets (``agent.spares``)."""
    started = time.perf_counter()
    live, removed, added = live_srg(
        request.fragments, request.stale, previous.live if previous else None
    )
    srg = live.srg
    base = previous.planned if previous else None
    replanning_started = time.perf_counter()
    planned = replan(
        base,
        srg,
        templates,
        request.relations,
        request.running,
        request.follow,
        request.appeared,
        (removed, added) if base is not None else None,
        planner,
        redundancy,
    )
    replanning_s = time.perf_counter() - replanning_started
    if previous is not None and planned.plan is previous.planned.plan:
        wanted, labels, isolated = previous.wanted, previous.labels, previous.isolated
    else:
        labels, isolated = template_needs(planned.plan.flow, templates)
        wanted = component_specs(planned.plan.flow, srg, keys, planned.plan.relations)
    if previous is not None and srg is previous.live.srg:
        data_hosts = previous.data_hosts
    else:
        data_hosts = {
            keys.data(edge_id): host
            for *_, edge_id, host in srg.edges(keys=True, data="host")
            if host
        }
    seconds = time.perf_counter() - started
    return Outcome(
        request,
        live,
        planned,
        wanted,
        labels,
        isolated,
        data_hosts,
        seconds,
        replanning_s,
        time.time_ns(),
    )


def template_needs(
    flow: DataFlow, templates: Sequence[Template]
) -> tuple[dict[str, frozenset[str]], frozenset[str]]:
    """What the templates of ``flow``'s components ask of where they run: the host labels each
    component requires (``Template.host_labels``, :func:`.placement.place`), and the
    components that run alone in a container of their own (``Template.isolation`` ``own``,
    :func:`.placement.group_containers`). O(components + templates)."""
    by_name = {template.name: template for template in templates}
    of = {c.id: by_name.get(c.template) for c in flow.components.values()}
    labels = {instance: t.host_labels if t else frozenset() for instance, t in of.items()}
    return labels, frozenset(instance for instance, t in of.items() if t and t.isolation == "own")


class BackgroundPlanner:
    """Plans on a daemon thread, one job at a time, and applies only current outcomes (module
    docstring). The loop calls :meth:`changed` on every change of what planning reads and
    :meth:`step` on every pass; neither waits for a plan."""

    def __init__(
        self,
        job: Callable[[Request, Outcome | None], Outcome],
        done: Callable[[], None] = lambda: None,
    ) -> None:
        self._job = job
        self._done = done
        """Called on the planning thread when an outcome is ready: the loop, which waits for
        events, takes it at once instead of on its next pass (up to 50 ms later)."""
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._request: Request | None = None
        self._result: Outcome | Exception | None = None
        self._latest: Outcome | None = None
        self._closed = False
        self.generation = 0
        """Changes of what planning reads so far."""
        self.applied = -1
        """The generation of the outcome last applied (none yet: behind)."""
        self.in_flight: Request | None = None
        self.superseded = 0
        """Outcomes dropped because the state changed while they were made."""
        self._appeared: set[str] = set()
        threading.Thread(target=self._run, name="ubitrack-planning", daemon=True).start()

    def changed(self, appeared: str | None = None) -> None:
        """What planning reads changed (``appeared``: a worker nothing ran, whose relations
        are to be planned again)."""
        self.generation += 1
        if appeared is not None:
            self._appeared.add(appeared)

    def step(self, snapshot: Callable[[int, frozenset[str]], Request]) -> Outcome | None:
        """The finished outcome if it is current (to apply), else ``None``; then, if the
        applied generation is behind and no job is under way, submit ``snapshot(generation,
        appeared)`` (the workers that appeared since the last submission, and those of a
        failed one). Raises a failed job's exception (the next call asks again)."""
        with self._lock:
            result, self._result = self._result, None
        current = None
        if result is not None:
            request, self.in_flight = self.in_flight, None
            if isinstance(result, Exception):
                self._appeared |= request.appeared if request is not None else set()
                raise result
            if result.request.generation == self.generation:
                current, self.applied = result, self.generation
            else:
                self.superseded += 1
        if self.applied != self.generation and self.in_flight is None:
            request = snapshot(self.generation, frozenset(self._appeared))
            self._appeared.clear()
            with self._lock:
                self.in_flight = self._request = request
                self._wake.notify()
        return current

    def close(self) -> None:
        with self._lock:
            self._closed = True
            self._wake.notify()

    def _run(self) -> None:
        while True:
            with self._lock:
                while self._request is None and not self._closed:
                    self._wake.wait()
                if self._closed:
                    return
                request, self._request = self._request, None
            try:
                outcome: Outcome | Exception = self._job(request, self._latest)
            except Exception as exc:
                outcome = exc
            else:
                self._latest = outcome  # outdated or not, the base of the next increment
            with self._lock:
                self._result = outcome
            self._done()
