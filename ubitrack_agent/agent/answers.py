"""The agent's answer to each query: which flow serves it, or why none can (issue 14, item 1).

The active agent publishes what :func:`query_answers` returns (wire format and keys:
:mod:`ubitrack_agent.net.answer`), so an application learns why nothing arrives without
reading the agent's log. Pure: the runtime publishes.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from ubitrack_agent.agent.flows import Plan, plan_name
from ubitrack_agent.net.answer import NOT_PLANNED, Answer
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.spec import ComponentSpec


def query_answers(
    plan: Plan,
    relations: Iterable[RelationId],
    keys: KeySpace,
    wanted: Mapping[str, ComponentSpec],
) -> dict[str, str]:
    """The answer to each of ``relations`` under ``plan`` (``wanted``: the component
    specifications of the plan), encoded, by answer key."""
    answers = {}
    for relation in relations:
        name = plan_name(relation)
        reason = plan.unsolved.get(name)
        served = reason is None and name in plan.relations
        components = sorted(plan.serving.get(name, ())) if served else []
        answer = Answer(
            relation=str(relation),
            served=served,
            key=keys.relation(relation),
            reason=None if served else reason or NOT_PLANNED,
            components={i: wanted[i].service for i in components if i in wanted},
        )
        answers[keys.answer(relation)] = answer.encode()
    return answers
