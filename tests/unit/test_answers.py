"""The agent's answers to queries: built from a plan, and read totally from the wire."""

from __future__ import annotations

import contextlib
import json

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.unit.test_agent_pure import KEYS, paper_fragments, specs_for
from ubitrack_agent.agent.announcements import build_srg
from ubitrack_agent.agent.answers import StaleJoins, query_answers, stale_edges
from ubitrack_agent.agent.flows import Plan, plan_relations
from ubitrack_agent.graph.dataflow import DataFlow
from ubitrack_agent.graph.templates import load_templates
from ubitrack_agent.net.answer import NOT_PLANNED, Answer, AnswerError, parse_answer
from ubitrack_agent.net.keys import RelationId

C_A = RelationId("C", "A", "6D")
NOWHERE = RelationId("NOPE", "A", "6D")
BAD_TYPE = RelationId("C", "A", "7D")


def test_each_query_is_answered_with_its_flow_or_the_planners_reason():
    plan, specs = specs_for(paper_fragments(), C_A, NOWHERE, BAD_TYPE)
    answers = {
        key: parse_answer(text.encode())
        for key, text in query_answers(plan, [C_A, NOWHERE, BAD_TYPE], KEYS, specs).items()
    }
    served = answers[KEYS.answer(C_A)]
    assert served.served and served.reason is None and served.key == KEYS.relation(C_A)
    assert served.components == {
        instance: spec.service for instance, spec in specs.items()
    }  # the figure-6 flow serves only C->A here
    assert "fusion" in served.components.values()
    lost = answers[KEYS.answer(NOWHERE)]
    assert not lost.served and "NOPE" in lost.reason and lost.components == {}
    refused = answers[KEYS.answer(BAD_TYPE)]
    assert not refused.served and "7D" in refused.reason


def test_a_query_not_planned_yet_says_so():
    (answer,) = query_answers(Plan(DataFlow()), [C_A], KEYS, {}).values()
    assert parse_answer(answer.encode()) == Answer(
        str(C_A), False, KEYS.relation(C_A), NOT_PLANNED, {}
    )


def test_a_relation_whose_frames_only_stale_edges_join_is_waiting_for_their_data():
    """The A.R.T. tracker's HT edge went quiet (stale): HT is in no live edge, so WT->HT is
    unsolved, but only until that edge's data comes again; a frame nobody announces, or a type
    no pattern yields, is an answer that holds."""
    fragments = {"art": paper_fragments()["art"]}
    stale = stale_edges(fragments, {"art/HT"})
    assert stale == {"art/HT": ("ART", "HT")}
    srg = build_srg(fragments, without=set(stale))
    wt_ht, art_wt_7d = RelationId("WT", "HT", "6D"), RelationId("ART", "WT", "7D")
    plan = plan_relations(srg, load_templates(), [wt_ht, NOWHERE, art_wt_7d])
    joins = StaleJoins(srg, stale)
    assert joins.waiting_for(wt_ht) == ["art/HT"]
    assert joins.waiting_for(NOWHERE) == []  # NOPE: no edge at all
    assert joins.waiting_for(art_wt_7d) == []  # joined already: another reason
    assert StaleJoins(srg, {}).waiting_for(wt_ht) == []
    answers = {
        key: parse_answer(text.encode())
        for key, text in query_answers(
            plan, [wt_ht, NOWHERE, art_wt_7d], KEYS, {}, srg, stale
        ).items()
    }
    waiting = answers[KEYS.answer(wt_ht)]
    assert waiting.waiting and not waiting.final and not waiting.served
    assert waiting.reason.startswith("waiting for data on art/HT (stale); until then: ")
    assert "HT" in waiting.reason.split("until then: ")[1]  # the planner's reason kept
    assert answers[KEYS.answer(NOWHERE)].final and answers[KEYS.answer(art_wt_7d)].final
    nothing_stale = query_answers(plan, [wt_ht], KEYS, {}, srg, {})
    assert parse_answer(nothing_stale[KEYS.answer(wt_ht)].encode()).final


def test_only_a_served_not_planned_or_waiting_answer_is_not_final():
    assert not GOOD.final
    assert not Answer("C->A:6D", False, "k", NOT_PLANNED).final
    assert not Answer("C->A:6D", False, "k", "waiting for data on a/b", waiting=True).final
    assert Answer("C->A:6D", False, "k", "no provider announces frame(s) C").final


GOOD = Answer("C->A:6D", True, "r/relation/C/A/6D/dynamic", None, {"fusion-1": "fusion"})


@pytest.mark.parametrize(
    "change, message",
    [
        ({"served": "yes"}, "served: expected bool"),
        ({"served": False}, "needs a reason"),
        ({"components": {"a": 1}}, "components"),
        ({"components": [1]}, "components: expected dict"),
        ({"relation": None}, "relation: expected str"),
        ({"reason": 3}, "reason: expected str"),
        ({"waiting": "yes"}, "waiting: expected bool"),
    ],
)
def test_a_malformed_answer_names_the_field(change, message):
    data = {**json.loads(GOOD.encode()), **change}
    with pytest.raises(AnswerError, match=message):
        parse_answer(json.dumps(data).encode())


def test_round_trip():
    assert parse_answer(GOOD.encode().encode()) == GOOD
    waiting = Answer("C->A:6D", False, "k", "waiting for data on a/b (stale)", waiting=True)
    assert parse_answer(waiting.encode().encode()) == waiting
    older = {k: v for k, v in json.loads(GOOD.encode()).items() if k != "waiting"}
    assert parse_answer(json.dumps(older).encode()) == GOOD  # an agent before the field


JSON = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=10),
    lambda children: (
        st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4)
    ),
    max_leaves=30,
)


@settings(max_examples=300, deadline=None)
@given(
    payload=st.binary(max_size=200)
    | JSON.map(lambda value: json.dumps(value).encode())
    | st.dictionaries(
        st.sampled_from(["relation", "served", "key", "reason", "components", "waiting"]), JSON
    ).map(lambda value: json.dumps(value).encode())
    | st.integers(1, 40).map(lambda depth: ("[" * depth * 100 + "]" * depth * 100).encode())
)
def test_parse_answer_is_total(payload):
    with contextlib.suppress(AnswerError):  # the only exception it may raise
        assert isinstance(parse_answer(payload), Answer)
