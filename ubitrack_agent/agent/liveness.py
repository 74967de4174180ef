"""Data liveness as the providers report it: a measured edge whose provider is alive but whose
data stopped counts as gone.

A provider's token says the process lives, not that its edges deliver: when ``ubitrack sim art``
dies while its DTrack adapter lives, the adapter still announces the A.R.T. edges. The silence
is observed where the data is: each provider (``io.provider``) reports which of its dynamic
push edges announcing a rate got no sample for ``max(20 / rate, 1 s)`` (*quiet*), on
``<root>/data/<provider>``, when that set changes and every second. The agent keeps the latest
report of each accepted provider and plans without the quiet edges (its *stale* edges) until a
report says they are back. It never reads a sample, so its work grows with the providers and
their reports (about one a second each), not with the sample rate.

Reports are network input: :func:`parse_report` returns the quiet edge names or raises
:class:`ReportError` with the reason, whatever the bytes, and :meth:`ProviderReports.take`
refuses a name that is not an edge of the provider's accepted fragment (a provider is the
authority on its own edges: it may report any of them quiet, as it may withdraw them); the
agent counts and logs each refusal (``rejected_liveness_reports``).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from ubitrack_agent.agent.announcements import MAX_EDGES
from ubitrack_agent.net.json_messages import MessageError, load_object
from ubitrack_agent.net.keys import validate_key_chunks

MAX_REPORT_BYTES = 64 * 1024
"""Largest liveness report read (a thousand edge names of 64 characters)."""


class ReportError(ValueError):
    """A liveness report is malformed or names edges its provider does not watch."""


def parse_report(payload: bytes) -> frozenset[str]:
    """The quiet edge names of a report ``{"quiet": [<name>, ...]}``; :class:`ReportError` if
    it is anything else."""
    try:
        data = load_object(payload, MAX_REPORT_BYTES)
    except MessageError as exc:
        raise ReportError(exc.reason) from None
    names = data.get("quiet")
    if set(data) != {"quiet"} or not isinstance(names, list) or len(names) > MAX_EDGES:
        raise ReportError(f'a report is {{"quiet": [at most {MAX_EDGES} edge names]}}')
    for name in names:
        try:
            validate_key_chunks(name, single_chunk=True)
        except ValueError as exc:
            raise ReportError(f"quiet edge name: {exc}") from None
    return frozenset(names)


class ProviderReports:
    """The quiet edges of each accepted provider, by its latest report. O(quiet edges) per
    report and per :attr:`stale`."""

    def __init__(self) -> None:
        self._quiet: dict[str, frozenset[str]] = {}

    def take(
        self, provider: str, names: frozenset[str], entries: Iterable[Mapping[str, Any]]
    ) -> None:
        """Keep ``provider``'s report of quiet edge ``names`` (its fragment's ``entries``);
        :class:`ReportError` if a name is not one of its announced edges."""
        ids = {f"{provider}/{name}" for name in names}
        unknown = sorted(ids - {entry["id"] for entry in entries})
        if unknown:
            raise ReportError(
                f"provider {provider!r} reports edges it does not announce: {unknown}"
            )
        self._quiet[provider] = frozenset(ids)

    def forget(self, provider: str) -> None:
        """Drop ``provider``'s report (it left, or announced again: its next report counts)."""
        self._quiet.pop(provider, None)

    @property
    def stale(self) -> frozenset[str]:
        """The edge ids reported quiet."""
        return frozenset().union(*self._quiet.values())
