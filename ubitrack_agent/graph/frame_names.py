"""Frame names a query may have meant (issue 31: "did you mean C->A?" for ``c a``).

The agent adds :func:`frame_hint` to its answer when a queried frame is in no announced edge,
so every application hears it with the reason (``UnsolvedRelation`` of the Python API, the
``subscribe`` and ``calibrate`` commands, any client reading the answer key). Closeness is
``difflib``'s ratio (Ratcliff and Obershelp's gestalt pattern matching), compared in lower
case.
"""

from __future__ import annotations

import difflib
from collections.abc import Collection, Iterable

CLOSE_RATIO = 0.6
"""Least ``difflib.SequenceMatcher`` ratio of a frame name to an announced one for a "did you
mean" (``difflib.get_close_matches``' default: ``HT`` for ``HTT``, ``Marker1`` for
``marker3``, not ``F1`` for ``F3``)."""


def close_frames(name: str, announced: Iterable[str], limit: int = 3) -> list[str]:
    """Announced frames ``name`` may have meant, best first (ties in name order): those equal
    but for case, then those within :data:`CLOSE_RATIO` of it, compared in lower case.
    O(announced x name length^2)."""
    wanted = name.lower()
    matcher = difflib.SequenceMatcher(b=wanted)
    scored = []
    for frame in set(announced) - {name}:
        matcher.set_seq1(frame.lower())
        if frame.lower() == wanted:
            scored.append((-2.0, frame))  # the same but for case: first
        elif matcher.real_quick_ratio() >= CLOSE_RATIO and matcher.ratio() >= CLOSE_RATIO:
            scored.append((-matcher.ratio(), frame))
    return [frame for _, frame in sorted(scored)[:limit]]


def frame_hint(source: str, target: str, announced: Collection[str]) -> str | None:
    """``did you mean C->A?`` when a frame of the relation ``source -> target`` is not
    announced but one close to it is (each unknown frame replaced by its best match; the other
    matches follow), else None."""
    hinted_source, hinted_target, others = source, target, []
    for frame in (source, target):
        if frame in announced or not (matches := close_frames(frame, announced)):
            continue
        if frame == source:
            hinted_source = matches[0]
        else:
            hinted_target = matches[0]
        others += [f"{match} for {frame}" for match in matches[1:]]
    if (hinted_source, hinted_target) == (source, target):
        return None
    alternatives = f" (or {', '.join(others)})" if others else ""
    return f"did you mean {hinted_source}->{hinted_target}{alternatives}?"
