"""Memoised plans: a ``graph.planner.plan`` answer reused for as long as what it was derived
from is unchanged, across events and across queries (issue [scale], "memoised sub-derivations
shared across queries").

``graph.planner.plan`` reads of the SRG only the query's *region*: the frames
``relevant_frames`` returns (the paper's "finding the relevant subgraph", section 5) and the
edges with both frames in it (``cut_frames`` splits the region, and ``saturate`` adds only
those edges, in a canonical order). Its answer is therefore a function of the query, the
planner's options, the templates, the region's frames, the query frames the SRG lacks (which
a calibration may introduce) and those edges with their attributes: that is the memo's key, the
edges taken as a set of ``(source, target, id, attributes)`` (the *fingerprint*). So

* an event outside a relation's region leaves its key, and a relation that must be checked
  again (say, every relation a new worker could serve: ``agent.replanning``) costs the key, not
  a plan;
* a provider that comes back restores the key its relations had before it left, whose plans
  are still held;
* the same query planned for several relations (or planned again after it was withdrawn) on
  the same region is planned once.

A query whose frames are absent or not connected is not memoised: the planner says so on its
first search, as cheaply as the key could be made. Failures to derive (``NoSolutionError``
after a search) are memoised like solutions. At most ``capacity`` answers are held, the least
recently used dropped first. The memo is used by one thread at a time (the agent's planning
thread); the solutions it returns are shared and must not be changed.

Cost per call: O(region's frames and edges) for the key (the region's breadth-first searches
and one pass over its edges), O(1) to look it up, plus one ``plan`` on a miss.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Hashable, Sequence

import networkx as nx

from ubitrack_agent.graph.planner import (
    DEFAULT_PER_RELATION,
    DEFAULT_SLACK,
    NoSolutionError,
    PartCache,
    PlanningError,
    Query,
    Solution,
    introducible_frames,
    plan,
    relevant_frames,
)
from ubitrack_agent.graph.templates import Template

DEFAULT_CAPACITY = 2048
"""Answers held: a few per relation for a hundred relations, each a few solutions' records."""


def region_key(
    srg: nx.MultiDiGraph,
    templates: Sequence[Template],
    query: Query,
    slack: int = DEFAULT_SLACK,
) -> Hashable:
    """What ``plan(srg, templates, query, slack=slack)`` depends on within the SRG (module
    docstring); :class:`PlanningError` if the query's frames are absent or not connected.
    O(region's frames and edges)."""
    new = introducible_frames(srg, templates, query)
    frames = frozenset(relevant_frames(srg, query.source, query.target, slack, new))
    edges = frozenset(
        (source, target, key, tuple(sorted(data.items())))
        for source in frames
        for target, parallel in srg.succ[source].items()
        if target in frames
        for key, data in parallel.items()
    )
    return new, frames, edges


class PlanMemo:
    """``graph.planner.plan`` with its answers memoised by region (module docstring); call it
    as ``plan``. ``hits`` and ``misses`` count the calls answered from the memo and planned."""

    def __init__(self, capacity: int = DEFAULT_CAPACITY) -> None:
        if capacity < 1:
            raise ValueError("a memo holds at least one answer")
        self.capacity = capacity
        self.hits = 0
        self.misses = 0
        self._answers: OrderedDict[Hashable, list[Solution] | NoSolutionError] = OrderedDict()
        self._templates: Sequence[Template] | None = None
        self.parts = PartCache()
        """The parts between cut frames the plans share (``graph.planner.PartCache``): a
        region that changed is planned again, but its rooms that did not are not."""

    def __len__(self) -> int:
        return len(self._answers)

    def copy(self) -> PlanMemo:
        """A memo holding the same answers (shared, not copied), counting on from here."""
        other = PlanMemo(self.capacity)
        other.hits, other.misses, other._templates = self.hits, self.misses, self._templates
        other.parts = self.parts
        other._answers = OrderedDict(self._answers)
        return other

    def __call__(
        self,
        srg: nx.MultiDiGraph,
        templates: Sequence[Template],
        query: Query,
        *,
        slack: int = DEFAULT_SLACK,
        per_relation: int = DEFAULT_PER_RELATION,
    ) -> list[Solution]:
        """``plan(srg, templates, query, slack=slack, per_relation=per_relation)``, from the
        memo when its key was planned before (the list is a copy; its solutions are
        shared)."""
        if templates is not self._templates:  # other templates: other answers
            self._answers.clear()
            self.parts = PartCache()
            self._templates = templates
        try:
            region = region_key(srg, templates, query, slack)
        except PlanningError:
            return plan(
                srg, templates, query, slack=slack, per_relation=per_relation, cache=self.parts
            )
        key = (query, slack, per_relation, region)
        answer = self._answers.get(key)
        if answer is None:
            self.misses += 1
            try:
                answer = plan(
                    srg, templates, query, slack=slack, per_relation=per_relation, cache=self.parts
                )
            except NoSolutionError as exc:
                answer = exc
            self._answers[key] = answer
            if len(self._answers) > self.capacity:
                self._answers.popitem(last=False)
        else:
            self.hits += 1
            self._answers.move_to_end(key)
        if isinstance(answer, NoSolutionError):
            raise NoSolutionError(*answer.args)
        return list(answer)
