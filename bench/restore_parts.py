"""What a container's restore is made of, seen from outside its processes (issue 28, failure
containment; issue 29, the gap after a killed container).

:class:`RestoreWatch` notes, on the wall clock, every worker's and container's liveliness token
coming and going and every report of the host manager on ``<root>/host/<name>/exited``;
:meth:`RestoreWatch.parts` turns them, with the restored components' own stamps (their status:
``stamps.created_ns`` and ``ready_ns``, ``services.worker``) and the samples the applications
received, into the parts of one restore, each in seconds after the kill:

* ``noticed_s`` and ``group_given_s`` (set by the caller from the host manager's status,
  ``last_restore``, where it has them): when the host manager noticed the death, and when it
  gave the group to a process (or spawned one for it);
* ``old_tokens_gone_s``: the killed process's first token seen leaving (zenoh noticed);
* ``reported_s``: the host manager's first ``restored`` report seen (it sends it once it gave
  the group to another process; it may arrive after the components started);
* ``container_up_s``: the new process's container token (it takes commands);
* ``components_created_s`` / ``components_ready_s``: each component's start and its end (every
  declaration made, its token last), in the container's order, and the first and last of each;
* ``components_up_s``: the first and last of their worker tokens seen;
* ``applications_back_s``: per application, its first correct sample stamped after the kill
  (its flow runs again; an application whose flow was elsewhere gets one a period later).

Same host, same clock: the trackers stamp on the wall clock this process reads. O(events seen +
components) per restore.
"""

from __future__ import annotations

import json
import threading
import time
from typing import Any

from bench.churn_bench import Applications
from tests.integration.chaos_faults import TRUE_WITHIN_M
from ubitrack_agent.net.host_protocol import Exited, ProtocolError
from ubitrack_agent.net.keys import KeyRejection, KeySpace
from ubitrack_agent.net.transport import fetch_latest

PUT = "SampleKind.PUT"


class RestoreWatch:
    """Tokens and exit reports with their arrival times, from :meth:`open` to :meth:`close`."""

    def __init__(self, session: Any, keys: KeySpace, host: str) -> None:
        self.session, self.keys, self.host = session, keys, host
        self.seen: list[tuple[float, str, str, str]] = []
        """(arrival, kind, change or report, key or payload)."""
        self._lock = threading.Lock()
        self._subscribers: list[Any] = []

    def _note(self, kind: str) -> Any:
        def note(sample: Any) -> None:
            with self._lock:
                if kind == "exited":
                    entry = (time.time(), kind, "report", sample.payload.to_bytes().decode())
                else:
                    entry = (time.time(), kind, str(sample.kind), str(sample.key_expr))
                self.seen.append(entry)

        return note

    def open(self) -> RestoreWatch:
        liveliness = self.session.liveliness()
        self._subscribers = [
            liveliness.declare_subscriber(self.keys.all_workers(), self._note("worker")),
            liveliness.declare_subscriber(self.keys.all_containers(), self._note("container")),
            self.session.declare_subscriber(self.keys.host_exited(self.host), self._note("exited")),
        ]
        return self

    def close(self) -> None:
        for subscriber in self._subscribers:
            subscriber.undeclare()
        self._subscribers = []

    def _pid(self, kind: str, key: str) -> tuple[str, int] | None:
        """The name and pid of a token's key (None if it is not one)."""
        if kind == "worker":
            try:
                instance, incarnation = self.keys.parse_worker(key)
            except ValueError:
                return None
            return instance, int(incarnation.partition(".")[0])
        token = self.keys.parse_token("container", key)
        if isinstance(token, KeyRejection):
            return None
        return token.name, int(token.incarnation.partition(".")[0])

    def parts(self, event: float, old_pid: int, apps: Applications) -> dict[str, Any]:
        """The restore after the kill at ``event`` (wall clock) of process ``old_pid``."""
        with self._lock:
            seen = [entry for entry in self.seen if entry[0] >= event]
        after = {"old_tokens_gone_s": None, "reported_s": None, "container_up_s": None}
        new_pid, restored = None, []
        for at, kind, _, text in seen:
            if kind == "exited":
                try:
                    report = Exited.parse(text.encode())
                except ProtocolError:
                    continue
                if report.reason == "restored":
                    new_pid = new_pid or report.pid
                    restored.append(report.instance)
                    after["reported_s"] = after["reported_s"] or round(at - event, 4)
        tokens_up = []
        for at, kind, change, key in seen:
            owner = self._pid(kind, key)
            if owner is None:
                continue
            if change != PUT and owner[1] == old_pid and after["old_tokens_gone_s"] is None:
                after["old_tokens_gone_s"] = round(at - event, 4)
            if change == PUT and owner[1] == new_pid:
                if kind == "container" and after["container_up_s"] is None:
                    after["container_up_s"] = round(at - event, 4)
                elif kind == "worker":
                    tokens_up.append(at - event)
        stamps = self._stamps(restored, event)
        created = [s["created_s"] for s in stamps.values()]
        ready = [s["ready_s"] for s in stamps.values()]
        return after | {
            "new_pid": new_pid,
            "components_restored": len(restored),
            "components_up_s": _first_last(tokens_up),
            "components_created_s": _first_last(created),
            "components_ready_s": _first_last(ready),
            "components": stamps,
            "applications_back_s": {str(r): back(apps, r, event) for r in apps.ids},
        }

    def _stamps(self, instances: list[str], event: float) -> dict[str, dict[str, float]]:
        """Each restored component's start and readiness after ``event`` (its status), in the
        order of their start."""
        stamps = {}
        for instance in instances:
            replies = fetch_latest(self.session, self.keys.status(instance), timeout=1.0)
            if not replies:
                continue
            own = json.loads(replies[0])["stamps"]
            stamps[instance] = {
                "created_s": round(own["created_ns"] * 1e-9 - event, 4),
                "ready_s": round(own["ready_ns"] * 1e-9 - event, 4),
            }
        return dict(sorted(stamps.items(), key=lambda item: item[1]["created_s"]))


def back(apps: Applications, relation: Any, event: float) -> float | None:
    """When ``relation``'s first correct sample stamped after ``event`` arrived, after it."""
    for arrival, stamp, error in apps.samples[relation]:
        if arrival >= event and stamp > event and error <= TRUE_WITHIN_M:
            return round(arrival - event, 4)
    return None


def _first_last(values: list[float]) -> list[float] | None:
    return [round(min(values), 4), round(max(values), 4)] if values else None
