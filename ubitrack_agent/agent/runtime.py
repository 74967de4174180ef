"""The agent: keeps the live SRG and the running data flow in step with what is announced.

It watches the liveliness tokens of providers, queries, workers and other agents, with
history, so a restarted agent rebuilds its whole state from them alone (``docs/protocol.md``):

* providers (``<root>/provider/<id>``): on appearance their SRG fragment is fetched from
  ``<root>/fragment/<id>`` and validated; on disappearance their edges leave the SRG;
* queries (``<root>/query/<from>/<to>/<type>/<kind>/<host>/<app>``): the relations
  applications want, and the hosts they run on; applications asking for the same relation
  share it;
* workers (``<root>/worker/<instance>/<incarnation>``): which components are alive, and in
  which processes; a token's removal affects only the incarnation that declared it, so a late
  removal of an earlier process's token never makes a running worker "vanish";
* agents (``<root>/agents/<id>``, ``<root>/agents/<id>/active``): one agent of a domain is
  active, the others stand by (:mod:`.election`). A standby does everything below but start,
  stop or rewire a worker: its plan is current, so when it takes over it adopts every worker
  that runs at once. A clean stop of the active agent with a standby alive hands over.

It also takes the providers' liveness reports (:mod:`.liveness`, on ``<root>/data/<provider>``):
an edge whose data stopped, as its provider observes, is planned without until its data
returns. The agent itself reads no sample.

After each batch of events it replans the relations the events can affect (:mod:`.replanning`; when
a worker nothing runs appeared, the relations it is a component of a derivation of, which the plan
may prefer), on a planning thread that never holds up the loop (:mod:`.planning`: an outcome made
before a newer event is dropped; plans of regions that did not change come from a memo,
:mod:`.plan_memo`), turns the merged data flow into worker specifications (:mod:`.materialise`) and
reconciles the running workers with them (:mod:`.reconcile`): start or stop (through a host
manager, over zenoh only: :mod:`.hosts`), or rewire in place with a control command. Each start
goes to the host :mod:`.placement` chooses, near the data the component reads, and into the
container there that :func:`.placement.group_containers` chooses (one per core the host may
use, a derivation's components together): the components of one container in one request, added
to it if it runs (no process start). A running component moves (started on the new host, then
its old process stopped) only when another host is better by the placement's margin; within a
host it never moves. A component whose container died and was restored by its host manager is
sent its current wiring once it is back. A start no host manager took is tried again on a later
pass. A worker that ends on its own (or whose host vanished with it) is started again where
placement says; a worker alive but not known (left by an earlier agent) is adopted if wanted,
stopped otherwise, but only once it has been unwanted for ``ORPHAN_GRACE_S`` after start-up
settled (``SETTLE_S``). Planning prefers the components that are alive, adopted or not, so a
restarted agent replans onto what runs. A stop the agent puts itself (for a worker no host
manager owns) is put again every ``STOP_RESEND_S`` while the worker's token stays up and nothing
wants it. Events are handled on the agent's own thread; zenoh callbacks only queue them.

Nothing from the network can end the agent: every key is parsed by ``KeySpace.parse_token``
and every fragment by :func:`.announcements.fragment_entries`, which return a value or a
rejection; rejections are counted, logged rate-limited and shown in the status
(:mod:`.problems`). Every handler runs under a :class:`.problems.Guard`, so even an unforeseen
exception is counted (``failed_<handler>``) and the agent carries on; a handler run on every
pass backs off while it keeps failing. A clean stop stops every worker it runs unless asked to
keep them (``stop(keep_workers=True)``, how ``ubitrack agent`` stops by default: a restart
then interrupts no data); should the loop itself ever fail, the workers are left running for
a restarted agent to adopt.
"""

from __future__ import annotations

import json
import logging
import queue
import threading
import time
from collections import Counter, defaultdict
from collections.abc import Callable, Iterable, Sequence
from typing import Any

from ubitrack_agent.agent.announcements import (
    MAX_FRAGMENT_BYTES,
    AnnouncementError,
    build_srg,
    fragment_entries,
)
from ubitrack_agent.agent.answers import query_answers, stale_edges
from ubitrack_agent.agent.clocks import EXACT, correct_clocks
from ubitrack_agent.agent.election import Election, new_agent_id
from ubitrack_agent.agent.flows import Plan, plan_name
from ubitrack_agent.agent.hosts import Hosts
from ubitrack_agent.agent.liveness import (
    MAX_REPORT_BYTES,
    ProviderReports,
    ReportError,
    parse_report,
)
from ubitrack_agent.agent.loop_times import LoopTimes
from ubitrack_agent.agent.materialise import relay_instance
from ubitrack_agent.agent.placement import group_containers, place
from ubitrack_agent.agent.plan_memo import PlanMemo
from ubitrack_agent.agent.planning import BackgroundPlanner, Outcome, Request, make_outcome
from ubitrack_agent.agent.problems import Guard, Problems
from ubitrack_agent.agent.reconcile import IN_PLACE, reconcile
from ubitrack_agent.agent.spares import DEFAULT_REDUNDANCY, Redundancy
from ubitrack_agent.agent.stamps import Stamps
from ubitrack_agent.agent.standby import standby_components
from ubitrack_agent.graph.srg import edge_ids
from ubitrack_agent.graph.templates import Template
from ubitrack_agent.net.address import is_misaddressed, put_addressed, reply_addressed
from ubitrack_agent.net.clock import Clock, ClockEstimate, serve_clock
from ubitrack_agent.net.config import Settings
from ubitrack_agent.net.encodings import JSON
from ubitrack_agent.net.host_protocol import STOP_COMMAND
from ubitrack_agent.net.keys import KeyRejection, KeySpace, RelationId
from ubitrack_agent.net.session import open_session
from ubitrack_agent.net.spec import HAND_OVER_HOLD_S, STANDBY_S, ComponentSpec, GroupSpec
from ubitrack_agent.net.transport import put_command

log = logging.getLogger("ubitrack.agent")

BATCH_WINDOW_S = 0.002
"""After an event, wait this long for more before replanning once for all of them."""
FRAGMENT_TIMEOUT_S = 0.3
FRAGMENT_ATTEMPTS = 8
"""A provider whose fragment query goes unanswered this often (over about 6 s) is rejected."""
MAX_LIVE_EDGES = 10_000
"""Most measured edges the live SRG holds: a fragment that would exceed it is rejected."""
RETIRE_S = 10.0
"""Longest time a worker the plan dropped keeps running, or a rewire waits, while the new
workers start (a cold start takes seconds on a loaded machine)."""
SETTLE_S = 1.5
"""After start-up, wait this long (for the liveliness history, which arrives as peers
reconnect) before deciding whether to be the active agent, and so before adopting, starting or
stopping workers."""
ORPHAN_GRACE_S = 2.0
"""A worker alive that no plan wants is stopped only after it has been unwanted this long
(and start-up has settled): the fragment that makes it wanted may still be on its way."""
REROUTE_S = 0.25
"""A component whose token vanished with no host manager to report its end (say, its host
manager died with it) is started again only if its token has not come back within this long: a
worker process that was a client of its host manager reaches the network through the hub and
declares its token again (gone for 2-8 ms in 5 trials at a load of 9-10: ``python -m
bench.reroute_bench``, ``docs/services.md``, "Links"). A machine that is lost costs this much
more before its components start elsewhere."""
STOP_RESEND_S = 1.0
"""A stop put on a worker's control key by the agent is put again this often while the
worker's token stays up."""
PUT = "SampleKind.PUT"
PLANNED = ("planned", "", "", 0)
"""Queued by the planning thread when a plan is ready: wakes the loop, which applies it."""
MAX_QUEUED_REPORTS = 10_000
"""Most liveness reports waiting for the agent's loop (providers put about one a second)."""
STATUS_REFRESH_S = 0.25
"""The status answer is rebuilt on every event, and at least this often (counters, rejections
and worker liveness also change between events)."""


class Agent:
    """The live agent on an open zenoh session (see the module docstring)."""

    def __init__(
        self,
        settings: Settings,
        templates: Sequence[Template],
        on_role: Callable[[bool], None] | None = None,
        redundancy: Redundancy = DEFAULT_REDUNDANCY,
    ) -> None:
        self.keys = KeySpace(settings.key_prefix)
        self.id = new_agent_id()
        self.election = Election(self.id)
        self.active = False
        self.handed_over = False
        """Whether a clean stop left the workers running for a standby agent to adopt."""
        self._keep_workers = False
        self._on_role = on_role
        self.templates = tuple(templates)
        self._plan_memo = PlanMemo()
        """The planner's answers by region, shared by every plan (:mod:`.plan_memo`)."""
        self._planner = BackgroundPlanner(
            lambda request, previous: make_outcome(
                request, previous, self.templates, self.keys, self._plan_memo, redundancy
            ),
            done=lambda: self._events.put(PLANNED),
        )
        self.counters: Counter[str] = Counter()
        self.problems = Problems(self.counters)
        self._guard = Guard(self.problems)
        self.last_plan_s: float | None = None
        self.loop_times = LoopTimes()
        """How long the loop's passes and handlers take (:mod:`.loop_times`, in the status)."""
        self.stamps = Stamps()
        """When each step from a query to its components' start happened (:mod:`.stamps`)."""
        """How long the latest plan applied took to make (on the planning thread)."""
        self.liveness = ProviderReports()
        self.stale: frozenset[str] = frozenset()
        self._reports: queue.SimpleQueue[tuple[str, Any]] = queue.SimpleQueue()
        self.dropped_reports = 0
        """Liveness reports dropped unread because ``MAX_QUEUED_REPORTS`` were waiting."""
        self.fragments: dict[str, list[dict[str, Any]]] = {}
        self.rejected: dict[str, str] = {}
        self.queries: dict[RelationId, set[str]] = defaultdict(set)
        self.application_hosts: dict[tuple[RelationId, str], str] = {}
        """The host each application asking for a relation runs on."""
        self.application_labels: dict[tuple[RelationId, str], frozenset[str]] = {}
        """The labels each application requires of the host running its relation's last hop."""
        self._data_hosts: dict[str, str] = {}
        """The host of each measured edge's provider, by data key (from the live SRG)."""
        self._labels: dict[str, frozenset[str]] = {}
        """The host labels each wanted component's template requires, by instance."""
        self.unplaced: dict[str, str] = {}
        """Why a wanted component has no host, by instance (the latest placement)."""
        self.alive: set[str] = set()
        self.incarnations: dict[str, dict[str, float]] = defaultdict(dict)
        """The incarnations (processes) whose token is up, by instance: when each appeared."""
        self._duplicate_stops: dict[tuple[str, str], float] = {}
        """Duplicate processes told to stop, (instance, incarnation): when to tell again."""
        self.running: dict[str, ComponentSpec] = {}
        self.wanted: dict[str, ComponentSpec] = {}
        """The specifications the plan wants, their inputs' clocks corrected (:mod:`.clocks`)
        once placed."""
        self._planned: dict[str, ComponentSpec] = {}
        """The specifications as the plan made them, before clock correction."""
        self.isolated: frozenset[str] = frozenset()
        """The plan's components whose template asks for a container of their own
        (``Template.isolation``, :func:`.placement.group_containers`)."""
        self.clock_problems: dict[str, str] = {}
        """Why a component's input clocks cannot be aligned within its tolerance."""
        self._host_name = settings.host_name
        self.plan: Plan | None = None
        self.srg = build_srg({})
        self._srg_listed: tuple[Any, list[dict[str, Any]]] = (None, [])
        """The SRG the status last listed, and its list (:meth:`_srg_status`)."""
        self.last_change_ns: int | None = None
        self._pending_fragments: dict[str, tuple[int, float]] = {}
        """Providers whose fragment is still to fetch: (attempts so far, next attempt)."""
        self._stopped: dict[str, float | None] = {}
        """Instances stopped: when to put the stop again (None: a host manager owns it)."""
        self._unwanted_since: dict[str, float] = {}
        self._retiring: dict[str, float] = {}
        self._standby: set[str] = set()
        """The retiring components kept beside the new flow (:mod:`.standby`)."""
        self._all_alive_since: float | None = None
        """Since when every wanted worker is alive (monotonic), for :meth:`_retire`."""
        self._held: dict[str, tuple[dict[str, Any], float]] = {}
        """Rewires waiting for the workers being started: command and deadline, by instance."""
        self._restored: dict[str, int] = {}
        """Components whose container was restored, with its new pid: their current wiring is
        sent once their token from that process is up."""
        self._unrouted: dict[str, float] = {}
        """Components whose token vanished with no host manager to report their end, until
        when they may come back before they are started again (``REROUTE_S``)."""
        self._events: queue.SimpleQueue[tuple[str, str, str, int]] = queue.SimpleQueue()
        """Liveliness events: kind, change, key and when zenoh handed it over (wall clock)."""
        self._stop = threading.Event()
        self._status_json = "{}"
        self.session = open_session(settings)
        self.clock = Clock.of(settings)
        """The reference clock the host managers measure their offsets to (``net.clock``)."""
        self.hosts = Hosts(self.session, self.keys, self.problems)
        liveliness = self.session.liveliness()
        self._watches = [
            liveliness.declare_subscriber(
                selector,
                lambda sample, kind=kind: self._events.put(
                    (kind, str(sample.kind), str(sample.key_expr), time.time_ns())
                ),
                history=True,
            )
            for kind, selector in (
                ("provider", self.keys.all_providers()),
                ("query", self.keys.all_queries()),
                ("worker", self.keys.all_workers()),
                ("agent", self.keys.all_agents()),
                ("active_agent", self.keys.all_active_agents()),
            )
        ]
        self._watches.append(
            self.session.declare_subscriber(self.keys.all_liveness(), self._queue_report)
        )
        self._started = time.monotonic()
        """When the watches were declared: their history arrives within ``SETTLE_S`` of it."""
        self._declared = [
            self._serve_status(self.keys.agent_member_status(self.id)),
            liveliness.declare_token(self.keys.agent_member(self.id)),
        ]
        self._declared_active: list[Any] = []
        self._answers: dict[str, str] = {}
        """The answer published for each queried relation, by answer key (:mod:`.answers`)."""
        self._answered: Plan | None = None

    # -- events -----------------------------------------------------------------------------

    def _handle(self, kind: str, change: str, key: str, received_ns: int = 0) -> bool:
        """Apply one liveliness event (``received_ns``: when zenoh handed it over); True if
        the SRG or the queries changed."""
        token = self.keys.parse_token(kind, key)
        if isinstance(token, KeyRejection):
            self.problems.report(
                token.counter, "ignored malformed %s key %r: %s", kind, token.key, token.reason
            )
            return False
        appeared = change == PUT
        if token.relation is not None:
            return self._on_query(
                token.relation, token.name, token.host, token.labels, appeared, received_ns
            )
        if kind == "provider":
            return self._on_provider(token.name, appeared)
        if kind == "agent":
            self.election.member(token.name, appeared)
            return False
        if kind == "active_agent":
            self.election.active(token.name, appeared)
            return False
        return self._on_worker(token.name, token.incarnation, appeared)

    def _on_provider(self, provider: str, appeared: bool) -> bool:
        self.liveness.forget(provider)  # a new process reports afresh
        if appeared:
            self._pending_fragments[provider] = (0, 0.0)
            return False
        self._pending_fragments.pop(provider, None)
        self.rejected.pop(provider, None)
        return self.fragments.pop(provider, None) is not None

    def _on_query(
        self,
        relation: RelationId,
        application: str,
        host: str,
        labels: frozenset[str],
        appeared: bool,
        received_ns: int = 0,
    ) -> bool:
        apps = self.queries[relation]
        before = bool(apps)
        if appeared:
            name = plan_name(relation)
            self.stamps.query(name, application, "received_ns", received_ns or None)
            self.stamps.query(name, application, "handled_ns")
            apps.add(application)
            self.application_hosts[relation, application] = host
            self.application_labels[relation, application] = labels
        else:
            apps.discard(application)
            self.stamps.forget_query(plan_name(relation), application)
            self.application_hosts.pop((relation, application), None)
            self.application_labels.pop((relation, application), None)
        if not apps:
            del self.queries[relation]
        return before != bool(apps)

    def _on_worker(self, instance: str, incarnation: str, appeared: bool) -> bool:
        """Apply a worker token event; True if a worker nothing ran appeared, so the plan may
        prefer it (the relations it may serve are then planned again: :mod:`.replanning`)."""
        incarnations = self.incarnations[instance]
        if appeared:
            known = instance in self.running or instance in self.alive
            incarnations.setdefault(incarnation, time.monotonic())
            self.alive.add(instance)
            return not known
        incarnations.pop(incarnation, None)
        self._duplicate_stops.pop((instance, incarnation), None)
        if incarnations:
            self.counters["earlier_incarnation_removals"] += 1
            return False  # an earlier process's token: the current one still runs
        del self.incarnations[instance]
        self.alive.discard(instance)
        self._stopped.pop(instance, None)
        if self.hosts.reports_exit_of(instance):
            self.hosts.await_exit(instance)  # its host manager's report, or status, ends it
            return False
        if instance in self.running:
            self._unrouted.setdefault(instance, time.monotonic() + REROUTE_S)
        return False

    def _restart_unrouted(self) -> None:
        """Start again the components whose token vanished with no host manager to report
        their end and has not come back within ``REROUTE_S``."""
        now = time.monotonic()
        for instance, deadline in list(self._unrouted.items()):
            if instance in self.alive or instance not in self.running:
                del self._unrouted[instance]  # back (through another link), or not wanted
            elif now > deadline:
                del self._unrouted[instance]
                self._held.pop(instance, None)
                del self.running[instance]
                self.counters["restarts"] += 1
                log.warning("%s: worker vanished, starting it again", instance)

    def _claim_unknown_workers(self) -> None:
        """Workers alive but not run by this agent (an earlier agent's, or one stopped that is
        wanted again before it ended): adopt the wanted ones, making sure of their wiring; stop
        the others once they have been unwanted for ``ORPHAN_GRACE_S`` after start-up settled
        and every announced fragment is in."""
        now = time.monotonic()
        for instance in sorted(self.alive - set(self.running)):
            wanted = self.wanted.get(instance)
            if self._stopped.get(instance, 0.0) is None:
                continue  # its host manager is stopping it; a start there replaces it
            if wanted is not None:
                self._adopt(instance, wanted)
            elif instance not in self._stopped and instance not in self._retiring:
                since = self._unwanted_since.setdefault(instance, now)
                if self._settled() and not self._pending_fragments and now - since > ORPHAN_GRACE_S:
                    self.counters["orphans_stopped"] += 1
                    log.info("%s: unknown worker, stopping it", instance)
                    self._stop_worker(instance)
        for instance in set(self._unwanted_since) - (self.alive - set(self.running)):
            del self._unwanted_since[instance]

    def _adopt(self, instance: str, wanted: ComponentSpec) -> None:
        """Take a running worker as ``wanted``, sending it that wiring."""
        self._unwanted_since.pop(instance, None)
        self._held.pop(instance, None)  # the whole wiring goes now
        retiring = self._retiring.pop(instance, None) is not None
        self._standby.discard(instance)
        stopped = self._stopped.pop(instance, None) is not None
        if not (retiring or stopped):
            self.counters["adopted"] += 1
        wiring = {k: wanted.as_dict()[k] for k in ("inputs", "relations", "parameters")}
        self._send_control(instance, wiring)
        self.running[instance] = wanted

    def _fetch_fragments(self) -> bool:
        """Fetch the fragments of providers that appeared; True if the SRG changed. The due
        providers are asked at once, so their waits overlap. A provider that does not answer is
        asked again (at most ``FRAGMENT_ATTEMPTS`` times, a little later each time), then
        rejected, so one broken provider never holds the agent up."""
        now = time.monotonic()
        asked = {
            provider: self.session.get(self.keys.fragment(provider), timeout=FRAGMENT_TIMEOUT_S)
            for provider, (_, due) in sorted(self._pending_fragments.items())
            if now >= due
        }
        changed = False
        for provider, replies in asked.items():
            took = self._guard.call(
                "fragment", self._take_fragment, provider, replies, default=False
            )
            changed = took or changed
        return changed

    def _take_fragment(self, provider: str, replies: Iterable[Any]) -> bool:
        """Accept or reject ``provider``'s fragment from the ``replies`` to its query, or ask
        again later if there is none; True if the SRG changed."""
        attempts, _ = self._pending_fragments.pop(provider)
        payload = next((r.ok.payload for r in replies if r.ok is not None), None)
        if payload is None and attempts + 1 < FRAGMENT_ATTEMPTS:
            self._pending_fragments[provider] = (
                attempts + 1,
                time.monotonic() + 0.05 * 2**attempts,
            )
            return False
        try:
            entries = fragment_entries(provider, self._fragment_bytes(provider, payload))
            self._check_room(provider, entries)
        except AnnouncementError as exc:
            self.problems.report("rejected_announcements", "rejected announcement: %s", exc)
            self.rejected[provider] = str(exc)
            return self.fragments.pop(provider, None) is not None
        self.liveness.forget(provider)  # its report may name edges it no longer announces
        self.fragments[provider] = entries
        self.rejected.pop(provider, None)
        return True

    def _fragment_bytes(self, provider: str, payload: Any) -> bytes:
        """The bytes of a fragment's payload, unread if it is too large to be one;
        :class:`AnnouncementError` if there is none."""
        if payload is None:
            where = self.keys.fragment(provider)
            raise AnnouncementError(f"provider {provider!r}: no fragment on {where}")
        if len(payload) > MAX_FRAGMENT_BYTES:  # refused before it is copied
            raise AnnouncementError(
                f"provider {provider!r}: fragment {len(payload)} bytes, at most "
                f"{MAX_FRAGMENT_BYTES}"
            )
        return payload.to_bytes()

    def _check_room(self, provider: str, entries: list[dict[str, Any]]) -> None:
        """:class:`AnnouncementError` if ``entries`` would take the live SRG past
        ``MAX_LIVE_EDGES``."""
        others = sum(len(e) for p, e in self.fragments.items() if p != provider)
        if others + len(entries) > MAX_LIVE_EDGES:
            raise AnnouncementError(
                f"provider {provider!r}: {len(entries)} edges would take the live SRG past "
                f"{MAX_LIVE_EDGES} edges"
            )

    # -- planning and reconciling -------------------------------------------------------------

    def _replan(self) -> None:
        """Apply the planning thread's outcome if it is current (no change since its snapshot),
        then hand it a snapshot of the newest state if the applied plan is behind; the state
        changes only when a whole plan is applied (a failure keeps the previous plan, and
        planning is asked again). Never waits for a plan (:mod:`.planning`)."""
        outcome = self._planner.step(self._snapshot)
        self.counters["superseded_plans"] = self._planner.superseded
        if outcome is not None:
            self._apply(outcome)

    def _worker(self, key: str) -> str:
        """The instance of a worker token's key (one :meth:`_handle` accepted)."""
        return self.keys.parse_worker(key)[0]

    def _snapshot(self, generation: int, appeared: frozenset[str]) -> Request:
        """What planning reads, as it is now (immutable: the planning thread reads it)."""
        return Request(
            generation,
            dict(self.fragments),
            self.stale,
            frozenset(self.queries),
            frozenset(self.running.keys() | self.alive),
            # A standby follows what the active agent runs (as an agent that has not planned
            # yet does: every alive component counts), so that it adopts all of it when it
            # takes over.
            follow=self.active,
            appeared=appeared,
            taken_ns=time.time_ns(),
        )

    def _apply(self, outcome: Outcome) -> None:
        """Make ``outcome``'s plan the agent's (its worker specifications if it changed)."""
        planned = outcome.planned
        if planned.plan is not self.plan:
            self.wanted, self._planned = dict(outcome.wanted), dict(outcome.wanted)
            self._labels, self.isolated = dict(outcome.labels), outcome.isolated
        self.srg, self.plan, self._data_hosts = planned.srg, planned.plan, dict(outcome.data_hosts)
        self.counters["replans"] += 1
        self.counters["relations_replanned"] += len(planned.replanned)
        self.counters["plans_memoised"] = self._plan_memo.hits
        self.counters["plans_made"] = self._plan_memo.misses
        self.counters["parts_memoised"] = self._plan_memo.parts.hits
        self.counters["parts_planned"] = self._plan_memo.parts.misses
        self.last_plan_s = outcome.seconds
        self._stamp_planned(outcome)
        for relation in sorted(planned.replanned, key=str):
            part = planned.parts[relation]
            if part.unsolved is not None:
                log.warning("cannot serve %s: %s", part.name, part.unsolved)

    def _stamp_planned(self, outcome: Outcome) -> None:
        """Stamp the queries this plan serves first (:mod:`.stamps`); forget the components
        no longer wanted or run. O(relations queried + components)."""
        plan = outcome.planned.plan
        for relation in outcome.request.relations:
            name = plan_name(relation)
            if name in plan.unsolved or name not in plan.relations:
                continue
            for steps in self.stamps.unplanned(name):
                steps["plan_asked_ns"] = outcome.request.taken_ns
                steps["plan_made_ns"] = outcome.made_ns
                steps["planned_ns"] = time.time_ns()
        self.stamps.keep_components(set(self.wanted) | set(self.running))

    def _queue_report(self, sample: Any) -> None:
        """Queue a liveness report (on zenoh's thread; bounded: a flood is dropped unread; one
        put on another key, which zenoh delivered here, refused: ``net.address``)."""
        if is_misaddressed(sample):
            self.problems.report(
                "misaddressed",
                "refused a liveness report put on another key than %s",
                sample.key_expr,
            )
        elif self._reports.qsize() < MAX_QUEUED_REPORTS:
            self._reports.put((str(sample.key_expr), sample.payload))
        else:
            self.dropped_reports += 1

    def _take_reports(self) -> bool:
        """Apply the queued liveness reports; True if the stale edges changed (then the agent
        replans)."""
        while not self._reports.empty():
            self._guard.call(
                "liveness_report", self._take_report, *self._reports.get_nowait(), default=None
            )
        self.counters["dropped_liveness_reports"] = self.dropped_reports
        return self._update_stale()

    def _take_report(self, key: str, payload: Any) -> None:
        """Keep one provider's report (:mod:`.liveness`); a report of a provider not accepted
        (yet) is ignored: it puts one every second."""
        try:
            provider = self.keys.parse_liveness(key)
        except ValueError as exc:
            self.problems.report("rejected_liveness_reports", "ignored liveness report: %s", exc)
            return
        if provider not in self.fragments:
            return
        try:
            if len(payload) > MAX_REPORT_BYTES:  # refused before it is copied
                raise ReportError(f"{len(payload)} bytes, at most {MAX_REPORT_BYTES}")
            names = parse_report(payload.to_bytes())
            self.liveness.take(provider, names, self.fragments[provider])
        except ReportError as exc:
            self.problems.report(
                "rejected_liveness_reports", "ignored liveness report of %r: %s", provider, exc
            )

    def _update_stale(self) -> bool:
        """The stale edges from the reports; True if they changed."""
        stale = self.liveness.stale
        if stale == self.stale:
            return False
        for edge_id in sorted(stale - self.stale):
            self.counters["stale_edges"] += 1
            log.warning("%s: no data, planning without it until it returns", edge_id)
        for edge_id in sorted(self.stale - stale):
            if edge_id.partition("/")[0] in self.fragments:  # (not an edge whose provider left)
                self.counters["returned_edges"] += 1
                log.warning("%s: data again, planning with it", edge_id)
        self.stale = stale
        return True

    def _settled(self) -> bool:
        """Start-up history has arrived: peers reconnect to a restarted agent within their
        retry period, and their tokens (workers to adopt) come with them."""
        return time.monotonic() - self._started > SETTLE_S

    def _reconcile(self) -> None:
        if not self._settled():
            return  # start nothing a worker of an earlier agent may still be doing
        placement = self._place()
        self.wanted = self._correct_clocks(placement)
        self._claim_unknown_workers()  # against this plan: what runs is adopted, not started
        actions = reconcile(self.running, self.wanted)
        restarted = {spec.instance for spec in actions.start}
        retired = set(actions.stop) - restarted
        standby = standby_components(self.running, retired, self._live_keys()) if retired else set()
        for instance in actions.stop:
            del self.running[instance]
            self._held.pop(instance, None)
            if instance in restarted:
                self._stop_worker(instance)  # replaced by another specification at once
            elif instance in standby:
                self._retiring[instance] = time.monotonic() + STANDBY_S
                self._standby.add(instance)
            else:
                self._retiring[instance] = time.monotonic() + RETIRE_S
        containers = _Containers(self, placement)
        started = self._start(
            [spec for spec in actions.start if spec.instance in placement], placement, containers
        )
        self._move(placement, restarted, containers)
        for spec in started:
            self.running[spec.instance] = spec
            self._stopped.pop(spec.instance, None)
            self._retiring.pop(spec.instance, None)  # wanted again before it was stopped
            self._standby.discard(spec.instance)
        for instance, command in actions.update:
            self._rewire(instance, command, wait=bool(started))
            self.running[instance] = self.wanted[instance]
        if started or actions.stop or actions.update:
            self.last_change_ns = time.time_ns()
            self.counters["reconfigurations"] += 1
            log.info(
                "reconfigured: %d started (%d waiting), %d stopped, %d rewired",
                len(started),
                len(actions.start) - len(started),
                len(actions.stop),
                len(actions.update),
            )

    def _live_keys(self) -> set[str]:
        """The data keys of the live SRG's measured edges. O(edges)."""
        return {self.keys.data(edge_id) for edge_id in edge_ids(self.srg)}

    def _place(self) -> dict[str, str]:
        """The host for each wanted instance (:mod:`.placement`): one with the labels its
        template requires and, for the producer of a queried relation, those its applications
        require; why some have none is kept in ``unplaced``."""
        application_hosts: dict[str, set[str]] = defaultdict(set)
        for (relation, _), host in self.application_hosts.items():
            application_hosts[self.keys.relation(relation)].add(host)
        asked: dict[str, set[str]] = defaultdict(set)  # relation key -> labels its readers ask
        for (relation, _), labels in self.application_labels.items():
            asked[self.keys.relation(relation)] |= labels
        required = {
            instance: self._labels.get(instance, frozenset()).union(
                *(asked.get(key, ()) for keys in spec.relations.values() for key in keys)
            )
            for instance, spec in self._planned.items()
        }
        current = {instance: placed.host for instance, placed in self.hosts.placements.items()}
        placement = place(
            self._planned,
            self.hosts.available(),
            self._data_hosts,
            application_hosts,
            current,
            required,
        )
        for instance in sorted(placement.unplaced.keys() - self.unplaced.keys()):
            log.warning("%s: cannot place it: %s", instance, placement.unplaced[instance])
        self.unplaced = dict(placement.unplaced)
        return dict(placement.hosts)

    def _correct_clocks(self, placement: dict[str, str]) -> dict[str, ComponentSpec]:
        """The planned specifications with their inputs' clocks aligned (:mod:`.clocks`, from
        the host managers' latest estimates, kept while a host manager is away; this agent's
        own host is the reference); why some cannot be is kept in ``clock_problems``."""
        estimates: dict[str, ClockEstimate | None] = dict(self.hosts.clocks())
        estimates[self._host_name] = EXACT
        placed = {i: p.host for i, p in self.hosts.placements.items()} | placement
        wanted, problems = correct_clocks(
            self._planned, self._data_hosts, placed, estimates, self.running
        )
        for instance in sorted(problems.keys() - self.clock_problems.keys()):
            log.warning("%s: %s", instance, problems[instance])
        self.clock_problems = problems
        return wanted

    def _start(
        self, specs: list[ComponentSpec], placement: dict[str, str], containers: _Containers
    ) -> list[ComponentSpec]:
        """Start ``specs`` on their hosts, in their containers: one request per container
        (:meth:`.hosts.Hosts.start_group`); those started."""
        by_container: dict[tuple[str, str], list[ComponentSpec]] = defaultdict(list)
        for spec in specs:
            host = placement[spec.instance]
            by_container[host, containers.of(spec.instance)].append(spec)
        started: set[str] = set()
        for (host, container), members in sorted(by_container.items()):
            for spec in members:
                self.stamps.component(spec.instance, "requested_ns")
            done = self.hosts.start_group(GroupSpec(container, tuple(members)), host)
            for instance in done:
                self.stamps.component(instance, "started_ns")
            started.update(done)
        return [spec for spec in specs if spec.instance in started]

    def _move(
        self, placement: dict[str, str], restarted: set[str], containers: _Containers
    ) -> None:
        """Start each running instance that placement puts on another host there, in its
        container there (its old process is then stopped as a duplicate,
        :meth:`_stop_duplicates`: make before break)."""
        for instance, spec in self.running.items():
            placed = self.hosts.placements.get(instance)
            target = placement.get(instance)
            if instance in restarted or placed is None or target in (None, placed.host):
                continue
            if instance not in self.alive:
                continue
            group = GroupSpec(containers.of(instance), (spec,))
            if self.hosts.start_group(group, target):
                self.counters["moves"] += 1
                log.info("%s: moved from host %s to %s", instance, placed.host, target)

    def _rewire(self, instance: str, command: dict[str, Any], wait: bool) -> None:
        """Send ``command`` to ``instance``, or, if ``wait``, hold it (merged with a command
        still held) until the workers being started are alive: a relation's old producer keeps
        publishing until the new one can (make before break, as :meth:`_retire`). A command to
        a worker not alive yet (still starting: it would not hear it) is held until it is."""
        held, _ = self._held.pop(instance, ({}, 0.0))
        command = {**held, **command}
        if wait or held or instance not in self.alive:
            self._held[instance] = (command, time.monotonic() + RETIRE_S)
        else:
            self._send_control(instance, command)

    def _stop_worker(self, instance: str) -> None:
        owned = self.hosts.stop(instance)
        self._stopped[instance] = None if owned else time.monotonic() + STOP_RESEND_S

    def _stop_duplicates(self) -> None:
        """An instance alive in several processes (say, one whose token came up as an earlier
        agent died, seen only after this agent started another; or one moving to another host)
        keeps the process its host manager placed, else the one seen first; each other one is
        stopped alone, on its incarnation's control key, again every ``STOP_RESEND_S`` while its
        token stays."""
        now = time.monotonic()
        for instance, seen in self.incarnations.items():
            if len(seen) < 2:
                continue
            keep = self._kept_incarnation(instance, seen)
            for incarnation in sorted(set(seen) - {keep}):
                if now >= self._duplicate_stops.get((instance, incarnation), 0.0):
                    self.counters["duplicate_stops"] += 1
                    log.warning("%s: also runs in %s: stopping that one", instance, incarnation)
                    key = self.keys.control_incarnation(instance, incarnation)
                    put_command(self.session, key, STOP_COMMAND)
                    self._duplicate_stops[instance, incarnation] = now + STOP_RESEND_S

    def _kept_incarnation(self, instance: str, seen: dict[str, float]) -> str:
        """The incarnation of ``instance`` to keep among ``seen`` (see :meth:`_stop_duplicates`)."""
        placement = self.hosts.placements.get(instance)
        if placement is not None:
            placed = [i for i in seen if i.partition(".")[0] == str(placement.pid)]
            if placed:
                return placed[0]
        return min(seen, key=lambda incarnation: (seen[incarnation], incarnation))

    def _resend_stops(self) -> None:
        """Put the stop again to workers the agent stopped itself whose token is still up
        (a stop put while the worker was still starting, or while its link to the agent was
        down, may be lost); never to one that is wanted again."""
        now = time.monotonic()
        for instance, due in list(self._stopped.items()):
            if due is not None and now > due and instance in self.alive:
                if instance in self.wanted or instance in self.running:
                    continue
                self.counters["stops_resent"] += 1
                put_command(self.session, self.keys.control(instance), STOP_COMMAND)
                self._stopped[instance] = now + STOP_RESEND_S

    def _retire(self) -> None:
        """Send the held rewires once every wanted worker is alive, and stop the workers the
        plan no longer wants, and move relation routes, ``HAND_OVER_HOLD_S`` after that (make
        before break: the old flow keeps the relation flowing while the new one starts, and
        keeps the key until the new producer's estimate is ready,
        ``ubitrack_agent.services.handover``); either after ``RETIRE_S`` at the latest. A
        rewire goes only to a worker that is alive."""
        all_alive = set(self.wanted) <= self.alive
        now = time.monotonic()
        if not all_alive:
            self._all_alive_since = None
        elif self._all_alive_since is None:
            self._all_alive_since = now
        handed_over = all_alive and now - self._all_alive_since >= HAND_OVER_HOLD_S
        for instance, (command, deadline) in list(self._held.items()):
            # A change of relation routes may take a key from its producer: as a retirement.
            due = handed_over if "relations" in command else all_alive
            if instance not in self.running:
                del self._held[instance]  # stopped meanwhile: nothing to rewire
            elif instance in self.alive and (due or now > deadline):
                del self._held[instance]
                self._send_control(instance, command)
                self.counters["held_rewires"] += 1
        for instance, deadline in list(self._retiring.items()):
            if (handed_over and instance not in self._standby) or now > deadline:
                del self._retiring[instance]
                self._standby.discard(instance)
                self._stop_worker(instance)

    def _send_control(self, instance: str, command: dict[str, Any]) -> None:
        put_command(self.session, self.keys.control(instance), json.dumps(command))
        self.stamps.component(instance, "rewired_ns")

    # -- one active agent per domain ----------------------------------------------------------

    def _elect(self) -> None:
        """Take over or step down as :mod:`.election` decides."""
        active = self.election.should_be_active(self.active, self._settled(), time.monotonic())
        if active and not self.active:
            self._become_active()
        elif self.active and not active:
            self._step_down()

    def _become_active(self) -> None:
        """Declare the active agent's tokens and status; the next reconcile adopts what runs."""
        liveliness = self.session.liveliness()
        self._answers, self._answered = {}, None  # published afresh
        self._declared_active = [
            self._serve_status(self.keys.agent_status()),
            serve_clock(self.session, self.keys.agent_clock(), self.clock),
            self.session.declare_queryable(
                self.keys.all_answers(),
                lambda query: self._guard.call(
                    "answer_query", self._reply_answers, query, default=None
                ),
            ),
            liveliness.declare_token(self.keys.agent_active(self.id)),
            liveliness.declare_token(self.keys.agent()),
        ]
        self.active = True
        self.counters["became_active"] += 1
        self.last_change_ns = time.time_ns()
        self._refresh_status()  # at once: the status the active key serves is no standby's
        log.warning("agent %s is the active agent of %s", self.id, self.keys.root)
        if self._on_role is not None:
            self._on_role(True)

    def _step_down(self) -> None:
        """Become a standby, leaving every worker running for the active agent to adopt."""
        self._undeclare_active()
        self.running.clear()
        self._retiring.clear()
        self._standby.clear()
        self._held.clear()
        self._stopped.clear()
        self._duplicate_stops.clear()
        self._unwanted_since.clear()
        self.counters["stepped_down"] += 1
        log.warning(
            "agent %s: another agent (%s) is active: standing by",
            self.id,
            ", ".join(sorted(self.election.actives - {self.id})),
        )
        if self._on_role is not None:
            self._on_role(False)

    def _publish_answers(self) -> None:
        """Put the answer to each query that changed since the last plan (:mod:`.answers`)."""
        if self.plan is None or self._answered is self.plan:
            return
        stale = stale_edges(self.fragments, self.stale) if self.stale else {}
        answers = query_answers(self.plan, self.queries, self.keys, self.wanted, self.srg, stale)
        for key, answer in answers.items():
            if self._answers.get(key) != answer:
                put_addressed(self.session, key, answer, encoding=JSON)
        self._answers, self._answered = answers, self.plan

    def _reply_answers(self, query: Any) -> None:
        """Reply with every published answer the query's key expression matches (on zenoh's
        thread: reads one reference)."""
        answers = self._answers
        for key, answer in answers.items():
            if query.key_expr.intersects(key):
                reply_addressed(query, key, answer, JSON)

    def _undeclare_active(self) -> None:
        for declared in self._declared_active:
            declared.undeclare()
        self._declared_active = []
        self.active = False

    # -- main loop and status -----------------------------------------------------------------

    def run(self) -> None:
        """Handle events until :meth:`stop`; every handler runs under the guard (module
        docstring)."""
        status_due = 0.0
        times = self.loop_times

        def periodic(name: str, handler: Callable[[], Any], default: Any) -> Any:
            with times.handler(name):
                return self._guard.periodic(name, handler, default)

        try:
            while not self._stop.is_set():
                batch = self._next_batch()
                started = time.perf_counter()
                with times.handler("liveliness"):
                    for event in batch:
                        if self._guard.call("liveliness", self._handle, *event, default=False):
                            worker = event[0] == "worker"
                            self._planner.changed(self._worker(event[2]) if worker else None)
                if periodic("fragments", self._fetch_fragments, False):
                    self._planner.changed()
                if periodic("liveness", self._take_reports, False):
                    self._planner.changed()
                periodic("hosts", self._reap_hosts, None)
                periodic("replan", self._replan, None)
                periodic("election", self._elect, None)
                if self.active:  # a standby keeps its state current but changes nothing
                    periodic("answers", self._publish_answers, None)
                    periodic("reconcile", self._reconcile, None)
                    periodic("retire", self._retire, None)
                    periodic("resend_stops", self._resend_stops, None)
                    periodic("duplicates", self._stop_duplicates, None)
                if batch or time.monotonic() > status_due:
                    periodic("status", self._refresh_status, None)
                    status_due = time.monotonic() + STATUS_REFRESH_S
                times.pass_done(time.perf_counter() - started)
        finally:
            self._close(stop_workers=self._stop.is_set())

    def _next_batch(self) -> list[tuple[str, str, str, int]]:
        """The liveliness events queued within ``BATCH_WINDOW_S`` of the next one (none after
        50 ms, or at once when a plan is ready: ``PLANNED``)."""
        try:
            first = self._events.get(timeout=0.05)
        except queue.Empty:
            return []
        if first is PLANNED:
            return []
        batch = [first]
        time.sleep(BATCH_WINDOW_S)
        while not self._events.empty():
            batch.append(self._events.get_nowait())
        return [event for event in batch if event is not PLANNED]

    def _reap_hosts(self) -> None:
        """Apply host managers' tokens and exit reports: forget the instances that ended (those
        lost with their host manager after ``REROUTE_S``); send the components of a restored
        container their current wiring once they are back."""
        for instance in self.hosts.reap(self.alive):
            self._held.pop(instance, None)
            if self.running.pop(instance, None) is not None:
                self.counters["restarts"] += 1
        for instance in self.hosts.take_lost():
            if instance in self.running:
                self._unrouted.setdefault(instance, time.monotonic() + REROUTE_S)
        self._restart_unrouted()
        restored, self.hosts.restored = self.hosts.restored, {}
        for instance, pid in restored.items():
            if instance in self.running:
                self._restored[instance] = pid
                self.counters["restored"] += 1
        for instance, pid in list(self._restored.items()):
            spec = self.running.get(instance)
            if spec is None:
                del self._restored[instance]
            elif any(i.partition(".")[0] == str(pid) for i in self.incarnations.get(instance, ())):
                del self._restored[instance]
                wiring = spec.as_dict()
                self._send_control(
                    instance,
                    {k: wiring[k] for k in IN_PLACE},
                )

    def _refresh_status(self) -> None:
        self.loop_times.window()
        self._status_json = json.dumps(self.status())

    def stop(self, keep_workers: bool = False) -> None:
        """End :meth:`run` (safe in a signal handler); a clean stop stops every worker it runs
        unless ``keep_workers`` (they serve on, for the agent started again to adopt)."""
        self._keep_workers = keep_workers
        self._stop.set()

    def latest_status(self) -> dict[str, Any]:
        """The status as last refreshed by the agent's thread (at most ``STATUS_REFRESH_S``
        old): safe to read from any thread."""
        return json.loads(self._status_json)

    def status(self) -> dict[str, Any]:
        """The agent's state: SRG, providers, queries, components, counters (JSON-ready).
        O(edges + applications + components): it is made again every ``STATUS_REFRESH_S``."""
        plan = self.plan
        placements = self.hosts.placements
        names = {relation: plan_name(relation) for relation in self.queries}
        hosts: dict[RelationId, set[str]] = defaultdict(set)
        for (relation, _), host in self.application_hosts.items():
            hosts[relation].add(host)
        return {
            "key_prefix": self.keys.root,
            "agent": self._roles(),
            "providers": {p: [e["id"] for e in entries] for p, entries in self.fragments.items()},
            "rejected_providers": dict(self.rejected),
            "stale_edges": sorted(self.stale),
            "srg": self._srg_status(),
            "queries": {names[r]: sorted(apps) for r, apps in self.queries.items()},
            "application_hosts": {names[r]: sorted(hosts[r]) for r in self.queries},
            "unsolved": dict(plan.unsolved) if plan else {},
            "relations": {
                name: {
                    "key": self.keys.relation(relation),
                    "spares": [
                        b.component or relay_instance(b.edge)
                        for b in plan.flow.spares.get(name, ())
                    ],
                }
                for name, relation in (plan.relations.items() if plan else ())
                if name not in plan.unsolved
            },
            "components": {
                instance: {
                    **spec.as_dict(),
                    "alive": instance in self.alive,
                    "processes": sorted(self.incarnations.get(instance, ())),
                    "host": placement.host if (placement := placements.get(instance)) else None,
                    "pid": placement.pid if placement else None,
                    "container": self.hosts.container_of(
                        instance, self.incarnations.get(instance, ())
                    ),
                    "derives": _derived_edges(plan, instance),
                }
                for instance, spec in self.wanted.items()
            },
            "standby_components": sorted(self._standby),
            "hosts": sorted(self.hosts.live),
            "host_info": {name: info.as_dict() for name, info in sorted(self.hosts.info.items())},
            "unplaced": dict(self.unplaced),
            "clock_problems": dict(self.clock_problems),
            "counters": dict(self.counters),
            "problems": dict(self.problems.last),
            "last_change_ns": self.last_change_ns,
            "planning": {
                "last_plan_s": self.last_plan_s,
                "under_way": self._planner.in_flight is not None,
            },
            "loop": self.loop_times.last,
            "stamps": self.stamps.as_dict(),
        }

    def _srg_status(self) -> list[dict[str, Any]]:
        """The live SRG's edges as the status lists them, made again only when a plan brings
        another SRG (the status is made every ``STATUS_REFRESH_S``: O(edges) each time
        otherwise, whatever happened)."""
        srg, listed = self._srg_listed
        if srg is not self.srg:
            listed = [
                {
                    "id": key,
                    "from": u,
                    "to": v,
                    "type": d["type"],
                    "static": d["static"],
                    "rate": d["quality"].rate,
                }
                for u, v, key, d in self.srg.edges(keys=True, data=True)
            ]
            self._srg_listed = (self.srg, listed)
        return listed

    def _roles(self) -> dict[str, Any]:
        """This agent's id and role, and the ids of the active and standby agents it sees."""
        active = (self.election.actives - {self.id}) | ({self.id} if self.active else set())
        return {
            "id": self.id,
            "role": "active" if self.active else "standby",
            "active": sorted(active),
            "standby": sorted(self.election.members - active),
        }

    def _serve_status(self, key: str) -> Any:
        """A queryable on ``key`` answering the latest status (on zenoh's thread)."""
        return self.session.declare_queryable(
            key,
            lambda query: self._guard.call(
                "status_query", self._reply_status, query, key, default=None
            ),
        )

    def _reply_status(self, query: Any, key: str) -> None:
        query.reply(key, self._status_json, encoding=JSON)

    def _close(self, stop_workers: bool) -> None:
        """Leave the network after a clean stop (``stop_workers``) or a failure of the loop.
        A clean stop of the active agent stops every worker it runs (every stop sent at once:
        ``Hosts.stop_all``), unless it was asked to keep them (``stop(keep_workers=True)``) or
        a standby agent is alive to adopt them (then it hands over: they keep running, as
        after a failure)."""
        standby = bool(set(self.election.standbys) - {self.id})
        self.handed_over = stop_workers and self.active and standby
        was_active = self.active
        self._undeclare_active()
        for declared in (*self._declared, *self._watches):
            declared.undeclare()
        if stop_workers and was_active and not standby and not self._keep_workers:
            self.hosts.stop_all(sorted({*self.running, *self._retiring}))
        elif self.handed_over:
            log.warning("handing over to the standby agent: the workers keep running")
        elif stop_workers and was_active:
            log.warning("stopped: the workers keep running for the agent started again")
        elif not stop_workers:
            log.error("the agent failed: its workers keep running for a restarted agent")
        self._planner.close()
        self.hosts.close()
        self.session.close()


class _Containers:
    """The container of each placed instance for one reconcile pass
    (:func:`.placement.group_containers` over the wanted components, with the containers the
    running ones are in), grouped when first asked: O(components + bindings)."""

    def __init__(self, agent: Agent, placement: dict[str, str]) -> None:
        self._agent, self._placement = agent, placement
        self._of: dict[str, str] | None = None

    def of(self, instance: str) -> str:
        if self._of is None:
            agent = self._agent
            cores = {host: info.cores for host, info in agent.hosts.info.items()}
            current = {
                i: p.container
                for i, p in agent.hosts.placements.items()
                if p.container is not None and p.host == self._placement.get(i)
            }
            isolating = {host for host, info in agent.hosts.info.items() if info.isolating}
            groups = group_containers(
                agent.wanted,
                self._placement,
                cores,
                isolated=agent.isolated,
                isolating_hosts=isolating,
                current=current,
            )
            self._of = {s.instance: name for name, g in groups.items() for s in g.components}
        return self._of[instance]


def _derived_edges(plan: Plan | None, instance: str) -> list[list[str]]:
    """The SRG edges ``[from, to, type]`` a component derives (none for a relay)."""
    component = plan.flow.components.get(instance) if plan is not None else None
    return [] if component is None else [[s, d, t] for _, s, d, t in component.outputs]
