"""The agent's answer to a query on the wire: which flow serves the relation, or why none can.

The active agent (``agent.answers``) puts one :class:`Answer` per queried relation on
``<root>/answer/<from>/<to>/<type>/<kind>`` (``KeySpace.answer``) whenever it changes, and
answers queries on those keys with the latest. Applications read it (``Relation.answer``;
``UnsolvedRelation`` carries the reason) and so do ``ubitrack subscribe`` and ``calibrate``.
JSON, one object::

    {"relation": "C->A:6D", "served": true, "reason": null,
     "key": "ubitrack/default/relation/C/A/6D/dynamic",
     "components": {"fusion-9f77ba81f1": "fusion", "inversion-8bad3b0925": "inversion"}}

``reason`` is the planner's explanation when ``served`` is false (``"no provider announces
frame(s) X"``, ``"unknown type '7D'"``, ...); ``components`` are the workers of the
relation's derivation, by instance, with their service (none when a measured edge answers it
directly). ``waiting`` (optional, false when absent) is true when the relation is unserved
only for now: edges whose data stopped (stale, ``agent.liveness``) would join its frames, so it
may be served as soon as their data comes again; the reason then names them. An application
waits on through such an answer, as through :data:`NOT_PLANNED`, where any other reason ends
its wait. :func:`parse_answer` is total: an :class:`Answer` or :class:`AnswerError`.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field

from ubitrack_agent.net import json_messages
from ubitrack_agent.net.json_messages import MessageError, load_object

NOT_PLANNED = "not planned yet"
"""The reason given for a query the agent has not planned (it arrived since the last plan):
an application waits on (``io.application``), where any other reason ends its wait."""

MAX_ANSWER_BYTES = 64 * 1024
"""An answer names a relation and a few components: well under a kilobyte."""


class AnswerError(ValueError):
    """An answer that breaks its form; the message names the field."""


@dataclass(frozen=True)
class Answer:
    """How the agent serves one queried relation, or why it cannot (module docstring)."""

    relation: str
    served: bool
    key: str
    reason: str | None = None
    components: dict[str, str] = field(default_factory=dict)
    waiting: bool = False
    """Unserved only until stale edges' data comes again (module docstring)."""

    @property
    def final(self) -> bool:
        """Whether the answer is that the relation cannot be served as things stand: not
        served, and neither merely not planned yet nor waiting for data."""
        return not self.served and self.reason != NOT_PLANNED and not self.waiting

    def encode(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)


def parse_answer(payload: bytes) -> Answer:
    """The answer in ``payload``; :class:`AnswerError` if it is not one."""
    try:
        data = load_object(payload, MAX_ANSWER_BYTES)
        read = json_messages.field
        components = read(data, "components", dict, optional=True) or {}
        if not all(isinstance(v, str) for v in components.values()):
            raise MessageError("malformed_request", "components: expected service names")
        answer = Answer(
            relation=read(data, "relation", str),
            served=read(data, "served", bool),
            key=read(data, "key", str),
            reason=read(data, "reason", str, optional=True),
            components=components,
            waiting=read(data, "waiting", bool, optional=True) or False,
        )
    except MessageError as exc:
        raise AnswerError(f"answer: {exc.reason}") from None
    if not answer.served and answer.reason is None:
        raise AnswerError("answer: an unserved relation needs a reason")
    return answer
