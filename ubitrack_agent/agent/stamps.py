"""When each step between an application's query and its flow happened on the agent.

Issue 28 asks for every application's first sample within 0.5 s of its query; to see where
that time goes, the agent stamps (wall clock, ``time.time_ns``: comparable with the other
processes of the host) each step it takes, and shows them in its status (``stamps``):

* per query (relation name, application): ``received_ns`` (its liveliness token's event, on
  zenoh's thread), ``handled_ns`` (the loop took the event), ``plan_asked_ns`` and
  ``plan_made_ns`` (the snapshot the first plan serving it was made from was taken, and that
  plan finished on the planning thread: ``agent.planning``), ``planned_ns`` (that plan
  applied on the loop); each the first time it happened for that query;
* per component: ``requested_ns`` and ``started_ns`` (its latest start request sent to a host
  manager and the reply taken), ``rewired_ns`` (its latest control command put).

Workers stamp the rest themselves (``ubitrack_agent.services.worker``: created, ready, first sample
per input, first publication per key); ``bench/containers_bench.py`` joins both.

Growth: O(queries + components) entries, each dropped when its query or component goes.
"""

from __future__ import annotations

import time
from typing import Any

QUERY_STEPS = ("received_ns", "handled_ns", "plan_asked_ns", "plan_made_ns", "planned_ns")
COMPONENT_STEPS = ("requested_ns", "started_ns", "rewired_ns")


class Stamps:
    """The agent's stamps (module docstring); used on the agent's loop only."""

    def __init__(self) -> None:
        self.queries: dict[str, dict[str, dict[str, int]]] = {}
        """By relation name, then application: the steps taken so far."""
        self.components: dict[str, dict[str, int]] = {}

    def query(self, relation: str, application: str, step: str, ns: int | None = None) -> None:
        """Stamp ``step`` of a query the first time it happens (``ns``: when, else now)."""
        steps = self.queries.setdefault(relation, {}).setdefault(application, {})
        steps.setdefault(step, time.time_ns() if ns is None else ns)

    def unplanned(self, relation: str) -> list[dict[str, int]]:
        """The steps of the queries for ``relation`` not planned yet. O(its applications)."""
        apps = self.queries.get(relation, {}).values()
        return [steps for steps in apps if "planned_ns" not in steps]

    def forget_query(self, relation: str, application: str) -> None:
        apps = self.queries.get(relation, {})
        apps.pop(application, None)
        if not apps:
            self.queries.pop(relation, None)

    def component(self, instance: str, step: str, ns: int | None = None) -> None:
        """Stamp ``step`` of a component (its latest time)."""
        self.components.setdefault(instance, {})[step] = time.time_ns() if ns is None else ns

    def keep_components(self, instances: set[str]) -> None:
        """Forget the components not in ``instances``. O(components stamped)."""
        for instance in set(self.components) - instances:
            del self.components[instance]

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready: queries by relation name then application, components by instance."""
        return {
            "queries": {
                relation: {application: dict(steps) for application, steps in apps.items()}
                for relation, apps in self.queries.items()
            },
            "components": {i: dict(s) for i, s in self.components.items()},
        }
