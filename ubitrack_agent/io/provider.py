"""Sensor-side API: announce SRG edges and publish their measurements.

A few lines make a tracker, camera or calibration database part of the middleware::

    edges = [
        EdgeAnnouncement("ART", "HT", "6D", rate=60.0, sigma=0.0005),
        EdgeAnnouncement("ART", "WT", "6D", static=True),
    ]
    with (
        open_session(settings) as session,
        Provider(session, KeySpace(settings.key_prefix), "art", edges, settings.host_name)
        as provider,
    ):
        provider.publish("ART_HT", pose)      # edge names default to <from>_<to>
        ...                                   # leaving the block closes the provider

The provider serves its SRG fragment (JSON, see ``docs/protocol.md``) on
``<root>/fragment/<id>``, naming the machine it runs on (``host``, default the machine's host
name: the agent places the workers reading its edges near it), then declares its liveliness
token ``<root>/provider/<id>``; the agent sees the token, fetches the fragment and adds the
edges to the live SRG. Each edge's data key also answers queries with the latest value, so a
worker started later still gets a static edge's value. Closing (leaving the ``with`` block,
calling :meth:`Provider.close`, or the process dying) removes the token and the agent replans;
an adapter ending on SIGTERM removes it first (:meth:`Provider.leave_on_signals`), before its
loop notices and closes.

While a dynamic push edge delivers, the provider also declares a liveliness token on the edge's
data key, withdrawn as soon as the edge misses its samples and declared again by its next
(``io.flowing``; :meth:`Provider.missed` for an adapter that knows frames came without the
edge): a producer of a relation key that needs the edge gives the key up then
(``services.handover``, rule 7), well before a silence tells it.

Data liveness is judged here, where the data is (``docs/protocol.md`` "Data liveness"): a
token says the process lives, not that its edges deliver. A dynamic push edge announcing a
``rate`` is *quiet* when :meth:`Provider.publish` was not called for it for
:func:`stale_after` seconds (20 periods, at least 1 s); the provider then puts a liveness
report, the JSON ``{"quiet": [<edge name>, ...]}`` listing every quiet edge, on
``<root>/data/<provider>`` (one chunk below ``data``, where an edge's data key always has two,
and a key the provider may write under access control). It puts the report again at once when
the set changes (an edge went quiet, or a sample of a quiet edge was published) and every
``SUMMARY_S`` anyway, so an agent that starts later (or missed one) learns the state within a
second. The agent plans without the quiet edges (``agent.liveness``) and so never reads a
sample itself: its work does not grow with the sample rate. Silence counts only while the
provider's checks run: a pause of its checks longer than ``PAUSE_S`` (the process starved of
CPU, or stopped in a debugger) is not held against any edge, and the samples queued meanwhile
get the time to be published. The check costs each publish one clock read and one assignment.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from ubitrack_agent.core import MEASUREMENT_TYPES, Measurement, encode
from ubitrack_agent.io.flowing import FlowingEdges
from ubitrack_agent.net.address import put_addressed
from ubitrack_agent.net.config import default_host_name
from ubitrack_agent.net.encodings import JSON
from ubitrack_agent.net.keys import KeySpace, validate_key_chunks
from ubitrack_agent.net.lifecycle import Closing, on_termination
from ubitrack_agent.net.transport import LatestValuePublisher

SRG_TYPES = frozenset(cls.SRG_TYPE for cls in MEASUREMENT_TYPES.values())
MODES = ("push", "pull")
STALE_PERIODS = 20.0
"""Periods of its announced rate without a sample after which an edge is quiet."""
STALE_MIN_S = 1.0
"""Shortest silence after which an edge is quiet, whatever its rate."""
PAUSE_S = 0.25
"""A longer time between two checks is a pause of the provider, not silence of its edges (it
checks every ``CHECK_S``)."""
CHECK_S = 0.05
"""How often a provider checks its edges for silence."""
SUMMARY_S = 1.0
"""How often a provider puts its liveness report when nothing changed."""


def stale_after(static: bool, mode: str, rate: float | None) -> float | None:
    """Seconds without a sample after which an edge is quiet: ``max(STALE_PERIODS / rate,
    STALE_MIN_S)`` (1 s at 60 Hz, 20 s at 1 Hz); ``None`` if it never is (static, pull, or no
    rate)."""
    if static or mode != "push" or not rate or rate <= 0:
        return None
    return max(STALE_PERIODS / rate, STALE_MIN_S)


class QuietEdges:
    """Which watched edges went quiet, from the times their samples were published (module
    docstring). Times are passed in (monotonic seconds); :meth:`published` runs on the
    publishing thread, :meth:`check` on the checking one. O(watched edges) per check."""

    def __init__(self, windows: Mapping[str, float], now: float) -> None:
        self.windows = dict(windows)
        self._last = dict.fromkeys(self.windows, now)  # a new edge has its whole window
        self._checked = now
        self.quiet: frozenset[str] = frozenset()

    def published(self, name: str, now: float) -> bool:
        """A sample of ``name`` was published; True if the edge was quiet (it is back)."""
        if name in self._last:
            self._last[name] = now
            if name in self.quiet:
                self.quiet = self.quiet - {name}
                return True
        return False

    def check(self, now: float) -> bool:
        """Update :attr:`quiet`; True if it changed. A pause since the last check longer than
        ``PAUSE_S`` is not counted as silence."""
        paused = now - self._checked
        if paused > PAUSE_S:
            for name, last in list(self._last.items()):
                self._last[name] = min(last + paused, now)
        self._checked = now
        quiet = frozenset(n for n, w in self.windows.items() if now - self._last[n] > w)
        changed, self.quiet = quiet != self.quiet, quiet
        return changed


@dataclass(frozen=True)
class EdgeAnnouncement:
    """One measured edge ``source -> target`` a provider publishes.

    ``sigma`` is the expected RMS error (metres, or pixels for 2D edges), ``rate`` in Hz and
    ``latency`` in seconds; the planner's cost model uses them (``docs/planner.md``).
    """

    source: str
    target: str
    type: str
    static: bool = False
    mode: str = "push"
    name: str | None = None
    sigma: float | None = None
    rate: float | None = None
    latency: float | None = None

    def __post_init__(self) -> None:
        for frame in (self.source, self.target):
            validate_key_chunks(frame, single_chunk=True)
        if self.type not in SRG_TYPES:
            raise ValueError(f"edge type {self.type!r} is not one of {sorted(SRG_TYPES)}")
        if self.mode not in MODES:
            raise ValueError(f"edge mode {self.mode!r} is not push or pull")
        if self.name is None:
            object.__setattr__(self, "name", f"{self.source}_{self.target}")
        validate_key_chunks(self.name, single_chunk=True)
        for field_name in ("sigma", "rate", "latency"):
            value = getattr(self, field_name)
            if value is not None and not (isinstance(value, int | float) and value >= 0):
                raise ValueError(f"edge {self.name}: {field_name} must be a number >= 0")

    @property
    def streams(self) -> bool:
        """Whether its samples come on their own (a dynamic push edge), so that their silence
        says it stopped (``io.flowing``)."""
        return not self.static and self.mode == "push"

    def as_json(self) -> dict[str, Any]:
        data: dict[str, Any] = {
            "name": self.name,
            "from": self.source,
            "to": self.target,
            "type": self.type,
            "static": self.static,
            "mode": self.mode,
        }
        for field_name in ("sigma", "rate", "latency"):
            if getattr(self, field_name) is not None:
                data[field_name] = getattr(self, field_name)
        return data


class Provider(Closing):
    """Announces a set of edges under ``provider_id`` and publishes their measurements.

    A context manager: ``with Provider(...) as provider:`` closes it on leaving the block.
    """

    def __init__(
        self,
        session: Any,
        keys: KeySpace,
        provider_id: str,
        edges: Iterable[EdgeAnnouncement],
        host: str | None = None,
    ) -> None:
        self.id = validate_key_chunks(provider_id, single_chunk=True)
        self.host = validate_key_chunks(host or default_host_name(), single_chunk=True)
        self.edges = {edge.name: edge for edge in edges}
        if not self.edges:
            raise ValueError("a provider needs at least one edge")
        self._fragment = json.dumps(
            {
                "provider": self.id,
                "host": self.host,
                "edges": [e.as_json() for e in self.edges.values()],
            }
        )
        self._publishers = {
            name: LatestValuePublisher(session, keys.measured(self.id, name)) for name in self.edges
        }
        self._queryable = session.declare_queryable(keys.fragment(self.id))
        self._thread = threading.Thread(target=self._serve_fragment, daemon=True)
        self._thread.start()
        windows = {
            name: window
            for name, edge in self.edges.items()
            if (window := stale_after(edge.static, edge.mode, edge.rate)) is not None
        }
        self._quiet = QuietEdges(windows, time.monotonic())
        self._session, self._report_key = session, keys.liveness(self.id)
        self._report_lock = threading.Lock()
        self._stop_reports = threading.Event()
        self._reporter = threading.Thread(target=self._report_liveness, daemon=True)
        if windows:
            self._reporter.start()
        self._token = session.liveliness().declare_token(keys.provider(self.id))
        self._closed = self._left = False
        self._leave_lock = threading.Lock()
        dynamic = [name for name, edge in self.edges.items() if edge.streams]
        self._flow = FlowingEdges(dynamic)
        self._flow_keys = {name: keys.measured(self.id, name) for name in dynamic}
        self._flow_tokens: dict[str, Any] = {}
        """The liveliness tokens of the edges delivering now, on their data keys."""
        self._flow_changed = threading.Condition()
        """Held around :attr:`_flow` and :attr:`_flow_tokens`; notified when the deadline
        :meth:`_watch_flow` waits for may have come sooner, or the provider left."""
        self._flow_watch = threading.Thread(target=self._watch_flow, daemon=True)
        if dynamic:
            self._flow_watch.start()

    def publish(self, edge_name: str, measurement: Measurement) -> None:
        """Publish one measurement of edge ``edge_name``; its type must match the edge's."""
        edge = self.edges.get(edge_name)
        if edge is None:
            raise KeyError(f"provider {self.id} announced no edge {edge_name!r}")
        if edge.type != measurement.SRG_TYPE:
            raise TypeError(f"edge {edge_name} is {edge.type}, got a {type(measurement).__name__}")
        self._publishers[edge_name].put(encode(measurement))
        now = time.monotonic()
        if self._quiet.published(edge_name, now):
            self._put_report()
        if self._flow.watches(edge_name):
            with self._flow_changed:
                if self._flow.published(edge_name, now):
                    self._sync_flow_tokens()
                    self._flow_changed.notify()

    def missed(self, edge_name: str) -> None:
        """A whole frame of the tracker came without edge ``edge_name`` (an adapter that knows,
        ``SensorAdapter.whole_frames``): the second in a row withdraws its token at once, with
        no margin for a late sample (``io.flowing``)."""
        if edge_name not in self.edges:
            raise KeyError(f"provider {self.id} announced no edge {edge_name!r}")
        with self._flow_changed:
            if self._flow.missed(edge_name):
                self._sync_flow_tokens()

    def _sync_flow_tokens(self) -> None:
        """Declare the token of each edge that delivers and withdraw the others'; flow lock
        held. O(edges), on a change only."""
        flowing = set() if self._left else self._flow.flowing
        for name in [n for n in self._flow_tokens if n not in flowing]:
            self._flow_tokens.pop(name).undeclare()
        for name in flowing - self._flow_tokens.keys():
            token = self._session.liveliness().declare_token(self._flow_keys[name])
            self._flow_tokens[name] = token

    def _watch_flow(self) -> None:
        """Withdraw the tokens of the edges gone silent, each at its deadline (``io.flowing``),
        until the provider leaves."""
        with self._flow_changed:
            while not self._left:
                stopped, next_check = self._flow.silent(time.monotonic())
                if stopped:
                    self._sync_flow_tokens()
                wait = None if next_check is None else max(next_check - time.monotonic(), 0.0)
                self._flow_changed.wait(wait)

    def _report_liveness(self) -> None:
        """Check the edges every ``CHECK_S``; put the report when it changed, and every
        ``SUMMARY_S`` (module docstring)."""
        summary_due = time.monotonic() + SUMMARY_S
        while not self._stop_reports.wait(CHECK_S):
            now = time.monotonic()
            if self._quiet.check(now) or now >= summary_due:
                self._put_report()
                summary_due = now + SUMMARY_S

    def _put_report(self) -> None:
        with self._report_lock:
            report = json.dumps({"quiet": sorted(self._quiet.quiet)})
            put_addressed(self._session, self._report_key, report, encoding=JSON)

    def _serve_fragment(self) -> None:
        for query in self._queryable:
            with query:
                query.reply(query.key_expr, self._fragment, encoding=JSON)

    def leave(self) -> None:
        """Withdraw the tokens alone (its edges', then its own), from any thread: each producer
        of a relation key that needs one of its edges (``services.handover``, rule 7), and the
        agent, learn at once that it is gone; samples still published meanwhile are delivered
        (and declare no token again). A second call, or :meth:`close` after it, does not
        undeclare them again."""
        with self._leave_lock:
            if self._left:
                return
            with self._flow_changed:
                self._left = True
                self._sync_flow_tokens()
                self._flow_changed.notify()
            self._token.undeclare()

    def leave_on_signals(self, stop: threading.Event) -> None:
        """On SIGTERM or SIGINT, :meth:`leave` at once, then set ``stop`` for the loop serving
        the sensor (replacing ``net.lifecycle.stop_on_signals``'s handler): the loop notices
        ``stop`` only after its read returns (an adapter's receive timeout, 0.1 s) and closes
        after that: the token ended 93 ms after the signal so, 0.5 ms now (median,
        ``python -m bench.provider_leave_bench``; ``docs/performance.md``, "A holder that lost a
        provider")."""

        def leave_then_stop() -> None:
            self.leave()
            stop.set()

        on_termination(leave_then_stop)

    def close(self) -> None:
        """Withdraw the announcement (token first, so the agent replans at once); a second
        call does nothing."""
        if self._closed:
            return
        self._closed = True
        self.leave()
        self._stop_reports.set()
        if self._reporter.is_alive():
            self._reporter.join(timeout=1.0)
        if self._flow_watch.is_alive():
            self._flow_watch.join(timeout=1.0)
        self._queryable.undeclare()
        self._thread.join(timeout=1.0)
        for publisher in self._publishers.values():
            publisher.undeclare()
