"""The access-control block (net.access) decides as docs/security.md says, evaluated the way
zenoh's policy decision point does: a matching deny wins, else an allow rule whose key
expression includes the message's key, else the default (deny); unknown subjects get nothing."""

import pytest
import zenoh

from ubitrack_agent.net.access import access_control, check_provider
from ubitrack_agent.net.keys import FIRST_CHUNKS, KeySpace, RelationId

KEYS = KeySpace("ubitrack/lab")
BLOCK = access_control(KEYS, ["ART", "camera", "store"])
RELATION = RelationId("WT", "HT", "6D")


def allowed(subject: str, message: str, key: str, flow: str = "ingress") -> bool:
    rules = {rule["id"]: rule for rule in BLOCK["rules"]}
    mine = [
        rules[r]
        for policy in BLOCK["policies"]
        if subject in policy["subjects"]
        for r in policy["rules"]
    ]
    matching = [
        rule
        for rule in mine
        if message in rule["messages"]
        and flow in rule["flows"]
        and any(zenoh.KeyExpr(k).includes(zenoh.KeyExpr(key)) for k in rule["key_exprs"])
    ]
    if any(rule["permission"] == "deny" for rule in matching):
        return False
    return bool(matching) or BLOCK["default_permission"] == "allow"


@pytest.mark.parametrize(
    "subject, message, key, flow",
    [
        ("agent", "put", KEYS.control("concat-1"), "ingress"),
        ("agent", "query", KEYS.host_request("lab1"), "ingress"),
        ("agent", "liveliness_token", KEYS.agent(), "ingress"),
        ("agent", "declare_queryable", KEYS.agent_status(), "ingress"),
        ("agent", "declare_queryable", KEYS.agent_clock(), "ingress"),
        ("agent", "reply", KEYS.agent_clock(), "ingress"),
        ("host", "query", KEYS.agent_clock(), "ingress"),  # a host manager's clock offset
        ("agent", "query", KEYS.agent_clock(), "ingress"),  # the agent's own host manager
        ("agent", "liveliness_token", KEYS.agent_member("18ea.1"), "ingress"),
        ("agent", "liveliness_token", KEYS.agent_active("18ea.1"), "ingress"),
        ("agent", "declare_queryable", KEYS.agent_member_status("18ea.1"), "ingress"),
        ("agent", "put", KEYS.answer(RELATION), "ingress"),
        ("agent", "declare_queryable", KEYS.all_answers(), "ingress"),
        ("application", "query", KEYS.answer(RELATION), "ingress"),
        ("application", "query", KEYS.all_agent_statuses(), "ingress"),
        ("host", "put", KEYS.pool("p1"), "ingress"),
        ("host", "put", KEYS.control("concat-1"), "ingress"),
        ("host", "put", KEYS.host_exited("lab1"), "ingress"),
        ("host", "liveliness_token", KEYS.host("lab1"), "ingress"),
        ("host", "reply", KEYS.host_request("lab1"), "ingress"),
        ("host", "put", KEYS.relation(RELATION), "ingress"),
        ("host", "put", KEYS.data("concat-1/out"), "ingress"),
        ("host", "put", KEYS.progress(RELATION), "ingress"),
        ("host", "liveliness_token", KEYS.worker("concat-1", "42.a1b2"), "ingress"),
        ("host", "liveliness_token", KEYS.container("vm-0", "42.a1b2"), "ingress"),
        ("host", "reply", KEYS.status("concat-1"), "ingress"),
        ("ART", "put", KEYS.measured("ART", "HT"), "ingress"),
        ("ART", "liveliness_token", KEYS.provider("ART"), "ingress"),
        ("ART", "reply", KEYS.fragment("ART"), "ingress"),
        ("store", "liveliness_token", KEYS.provider("store.C_HT"), "ingress"),
        ("store", "put", KEYS.measured("store.C_HT", "C_HT"), "ingress"),
        ("store", "reply", KEYS.store("store"), "ingress"),
        ("application", "liveliness_token", KEYS.query(RELATION, "app", "hmd"), "ingress"),
        ("application", "query", KEYS.relation(RELATION), "ingress"),
        ("application", "declare_subscriber", KEYS.relation(RELATION), "ingress"),
        ("application", "query", KEYS.all_statuses(), "ingress"),
        ("operator", "query", KEYS.store("store"), "ingress"),
        ("application", "put", KEYS.relation(RELATION), "egress"),
        # providers' data and liveness reports (their puts drop): tools and applications read
        ("application", "declare_subscriber", KEYS.measured("ART", "HT"), "ingress"),
        ("operator", "declare_subscriber", KEYS.measured("store.C_HT", "C_HT"), "ingress"),
        ("application", "query", KEYS.measured("ART", "HT"), "ingress"),
        ("application", "declare_subscriber", KEYS.all_liveness(), "ingress"),
        ("application", "declare_liveliness_subscriber", KEYS.pattern("**"), "ingress"),
        ("application", "declare_subscriber", KEYS.agent_status(), "ingress"),
        # components' outputs (the flow's wiring): only the agent and host managers, workers
        ("agent", "declare_subscriber", KEYS.data("concat-1/out"), "ingress"),
        ("host", "declare_subscriber", KEYS.data("concat-1/out"), "ingress"),
        ("host", "query", KEYS.data("concat-1/out"), "ingress"),  # a time query
        ("agent", "declare_subscriber", KEYS.pattern("**"), "ingress"),
    ],
)
def test_each_role_may_do_its_job(subject, message, key, flow):
    assert allowed(subject, message, key, flow)


@pytest.mark.parametrize(
    "subject, message, key, flow",
    [
        (
            "host",
            "put",
            KEYS.measured("ART", "HT"),
            "ingress",
        ),  # workers never write a provider's data
        ("agent", "reply", KEYS.measured("store.C_HT", "C_HT"), "ingress"),
        ("host", "liveliness_token", KEYS.agent(), "ingress"),
        ("host", "declare_queryable", KEYS.agent_clock(), "ingress"),  # no false reference
        ("ART", "reply", KEYS.agent_clock(), "ingress"),
        ("host", "liveliness_token", KEYS.agent_active("18ea.1"), "ingress"),  # no takeover
        ("ART", "put", KEYS.answer(RELATION), "ingress"),  # only the agent answers queries
        ("application", "liveliness_token", KEYS.agent_member("18ea.1"), "ingress"),
        (
            "host",
            "query",
            KEYS.host_request("lab1"),
            "ingress",
        ),  # only the agent asks host managers
        ("camera", "put", KEYS.measured("ART", "HT"), "ingress"),  # another provider's data
        ("camera", "liveliness_token", KEYS.provider("ART"), "ingress"),
        ("ART", "put", KEYS.relation(RELATION), "ingress"),
        ("ART", "put", KEYS.control("concat-1"), "ingress"),
        ("ART", "liveliness_token", KEYS.worker("concat-1", "42.a1b2"), "ingress"),
        ("application", "put", KEYS.control("concat-1"), "ingress"),
        ("application", "put", KEYS.pool("p1"), "ingress"),
        ("application", "put", KEYS.relation(RELATION), "ingress"),
        ("application", "put", KEYS.measured("ART", "HT"), "ingress"),
        ("application", "liveliness_token", KEYS.worker("concat-1", "42.a1b2"), "ingress"),
        ("application", "liveliness_token", KEYS.provider("ART"), "ingress"),
        ("application", "query", KEYS.store("store"), "ingress"),  # save requests: operators only
        ("application", "query", KEYS.host_request("lab1"), "ingress"),
        ("intruder", "put", KEYS.measured("ART", "HT"), "ingress"),
        ("intruder", "declare_subscriber", KEYS.relation(RELATION), "ingress"),
        ("intruder", "put", KEYS.relation(RELATION), "egress"),  # it receives nothing either
        # a component's output is the flow's wiring, for components alone (net.access)
        ("application", "declare_subscriber", KEYS.data("concat-1/out"), "ingress"),
        ("operator", "declare_subscriber", KEYS.data("concat-1/out"), "ingress"),
        ("ART", "declare_subscriber", KEYS.data("concat-1/out"), "ingress"),
        ("application", "query", KEYS.data("concat-1/out"), "ingress"),
        ("application", "declare_subscriber", KEYS.data("relay-0123456789/out"), "ingress"),
        # wildcards that include a component's key are refused as a whole
        ("application", "declare_subscriber", KEYS.pattern("data", "**"), "ingress"),
        ("operator", "declare_subscriber", KEYS.pattern("**"), "ingress"),
        ("camera", "declare_subscriber", KEYS.pattern("data", "*", "*"), "ingress"),
    ],
)
def test_nothing_else_is_allowed(subject, message, key, flow):
    assert not allowed(subject, message, key, flow)


def test_subjects_are_certificate_common_names_and_the_default_is_deny():
    assert BLOCK["enabled"] and BLOCK["default_permission"] == "deny"
    assert all(set(s) == {"id", "cert_common_names"} for s in BLOCK["subjects"])
    assert all(k.startswith("ubitrack/lab/") for r in BLOCK["rules"] for k in r["key_exprs"])


@pytest.mark.parametrize("name", ["agent", "operator", "a/b", "*", ""])
def test_provider_names_must_not_be_roles_or_wildcards(name):
    with pytest.raises(ValueError):
        check_provider(name)


EVERY_KIND = [
    KEYS.agent(),
    KEYS.agent_member("18ea.1"),
    KEYS.answer(RELATION),
    KEYS.container("c1", "42.a1b2"),
    KEYS.control("concat-1"),
    KEYS.data("concat-1/out"),
    KEYS.fragment("ART"),
    KEYS.host("lab1"),
    KEYS.container_left("c1"),
    KEYS.pool("p1"),
    KEYS.progress(RelationId("WT", "HT", "6D", static=True)),
    KEYS.provider("ART"),
    KEYS.query(RELATION, "app", "hmd"),
    KEYS.relation(RELATION),
    KEYS.status("concat-1"),
    KEYS.store("store"),
    KEYS.truth("WT", "HT"),
    KEYS.worker("concat-1", "42.a1b2"),
]
"""One key of each kind the key space builds."""


def test_the_first_chunks_are_every_kind_of_key():
    kinds = {key.removeprefix(KEYS.root + "/").split("/")[0] for key in EVERY_KIND}
    assert kinds == set(FIRST_CHUNKS)


@pytest.mark.parametrize("key", [k for k in EVERY_KIND if k != KEYS.data("concat-1/out")])
def test_an_application_may_subscribe_to_every_key_but_components_outputs(key):
    assert allowed("application", "declare_subscriber", key)
