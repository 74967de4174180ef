"""Zenoh access control for the middleware's keys: who may write what (``docs/security.md``).

:func:`access_control` builds zenoh's own ``access_control`` block (rules, subjects matched by
the common name of each process's TLS client certificate, policies) for one key root. It is
enforced by the hub, a zenoh router every other process reaches as a client over mutual TLS,
so no message bypasses it. Everything not granted is denied (``default_permission: deny``): a
certificate with an unknown common name can neither read nor write.

Roles, by certificate common name:

* ``agent``: the agent and what it starts on its machine (its host manager, that host's
  workers);
* ``host``: a host manager on another machine and its workers;
* ``application``: applications (query tokens; reading);
* ``operator``: an application that may also send calibration store save requests;
* any other name is a provider id (sensor, database, calibration store): it may announce that
  provider and ``<id>.<suffix>`` ones (a store's ``store.C_HT``) and write their data only.

Reading (liveliness, subscriptions and queries on relations, fragments, statuses, the agent's
clock, progress, truth, providers' data) is granted to every known role; writes are granted per
role (see the tables in ``docs/security.md``). Worker writes on data keys exclude every
provider's data.

Only ``agent`` and ``host`` may subscribe to and query a **component's output data key**
(``R/data/<instance>/<port>``, ``agent.materialise``): the data flow's own wiring, which the
agent gives only to other components (least privilege: an application reads its relation key,
and a reader that stops reading costs the component's container a wait of up to
``net.config.DROP_WAIT_US`` on each put to it until it drops them; until session 27 these
puts waited up to 5 s, congestion control BLOCK, ``net.transport``). The other
roles may subscribe to every kind of key but ``R/data`` by name, to providers' data keys
(``R/data/X/**``, ``R/data/X.*/**``, whose puts drop) and to the providers' liveness reports
(``R/data/*``). This is an allow list, not a deny of the component keys, because zenoh applies
a rule to a message only when the rule's key expression *includes* the message's (a
subscriber on ``R/data/**`` or ``R/**`` is included in no deny rule on ``R/data/*/*``; zenoh's
access-control manual, "Guidelines for configuring ACL": "supersets and partial overlap
between rule key expressions and message key [...] are not considered valid matches"; deny >
allow > default). So a wildcard subscriber that would reach a component's key is refused as a
whole; ``ingress`` is where the router sees a client's ``declare_subscriber`` (the same
manual: a router "receives" a message on ingress), and a refused declaration is never routed,
so no put waits for it. Liveliness subscriptions and queries stay granted on ``R/**`` (tokens
carry no data).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

from ubitrack_agent.net.keys import FIRST_CHUNKS, KeySpace, validate_key_chunks

AGENT, HOST, APPLICATION, OPERATOR = "agent", "host", "application", "operator"
ROLES = (AGENT, HOST, APPLICATION, OPERATOR)
"""Certificate common names with a fixed role; any other common name is a provider id."""

WRITES = ("put", "delete")
SERVES = ("declare_queryable", "reply")
LIVELINESS_READS = ("declare_liveliness_subscriber", "liveliness_query")
READS = ("declare_subscriber", *LIVELINESS_READS)
EVERY_MESSAGE = (*WRITES, *SERVES, *READS, "query", "liveliness_token")


def _rule(
    rule_id: str,
    messages: Iterable[str],
    key_exprs: Iterable[str],
    permission: str = "allow",
    flow: str = "ingress",
) -> dict[str, Any]:
    return {
        "id": rule_id,
        "messages": list(messages),
        "flows": [flow],
        "permission": permission,
        "key_exprs": list(key_exprs),
    }


def _provider_keys(keys: KeySpace, provider: str) -> dict[str, list[str]]:
    """The keys of provider ``provider`` and its ``<provider>.<suffix>`` family, by use."""
    family = (provider, f"{provider}.$*")
    return {
        "token": [keys.pattern("provider", p) for p in family],
        "fragment": [keys.pattern("fragment", p) for p in family],
        "data": [keys.pattern("data", p, "**") for p in family],
    }


def _all_provider_data(keys: KeySpace, providers: Sequence[str]) -> list[str]:
    """The data keys of every provider in ``providers``: O(providers) key expressions."""
    return [key for p in providers for key in _provider_keys(keys, p)["data"]]


def _common_rules(keys: KeySpace, providers: Sequence[str]) -> list[dict[str, Any]]:
    """Granted to every known role: receiving anything, and reading all but components' data
    keys (the module's docstring)."""
    provider_data = _all_provider_data(keys, providers)
    readable = [
        keys.agent_status(),
        keys.agent_clock(),
        keys.all_agent_statuses(),
        keys.all_statuses(),
        *(keys.pattern(kind, "**") for kind in ("relation", "progress", "truth")),
        *provider_data,
        keys.all_answers(),
        keys.pattern("fragment", "*"),
    ]
    subscribable = [
        *(keys.pattern(kind, "**") for kind in FIRST_CHUNKS if kind != "data"),
        keys.all_liveness(),
        *provider_data,
    ]
    return [
        _rule("receive", EVERY_MESSAGE, [keys.pattern("**")], flow="egress"),
        _rule("liveliness", LIVELINESS_READS, [keys.pattern("**")]),
        _rule("subscribe", ["declare_subscriber"], subscribable),
        _rule("read", ["query"], readable),
    ]


def _role_rules(keys: KeySpace, providers: Sequence[str]) -> list[dict[str, Any]]:
    """The write rules of the fixed roles."""
    outputs = [keys.pattern(kind, "**") for kind in ("data", "relation", "progress")]
    provider_data = _all_provider_data(keys, providers)
    host_requests = keys.pattern("host", "*", "request")
    controls = keys.pattern("control", "**")
    return [
        _rule("subscribe-all", ["declare_subscriber"], [keys.pattern("**")]),
        _rule("query-data", ["query"], [keys.pattern("data", "**")]),
        _rule(
            "worker-tokens",
            ["liveliness_token"],
            [keys.all_workers(), keys.all_pools(), keys.all_containers()],
        ),
        _rule("worker-outputs", [*WRITES, *SERVES], outputs),
        _rule("worker-statuses", SERVES, [keys.all_statuses()]),
        _rule("not-provider-data", [*WRITES, *SERVES], provider_data, permission="deny"),
        _rule("host-token", ["liveliness_token"], [keys.all_hosts()]),
        _rule("host-requests", SERVES, [host_requests]),
        _rule("host-writes", WRITES, [keys.all_host_exits(), keys.all_pools(), controls]),
        _rule("agent-token", ["liveliness_token"], [keys.agent(), keys.pattern("agents", "**")]),
        _rule(
            "agent-status",
            SERVES,
            [keys.agent_status(), keys.agent_clock(), keys.all_agent_statuses()],
        ),
        _rule("agent-requests", ["query"], [host_requests]),
        _rule("agent-answers", [*WRITES, *SERVES], [keys.all_answers()]),
        _rule("application-queries", ["liveliness_token"], [keys.all_queries()]),
        _rule("store-requests", ["query"], [keys.pattern("store", "*")]),
    ]


ROLE_RULES: dict[str, tuple[str, ...]] = {
    AGENT: (
        "subscribe-all",
        "query-data",
        "worker-tokens",
        "worker-outputs",
        "worker-statuses",
        "not-provider-data",
        "host-token",
        "host-requests",
        "host-writes",
        "agent-token",
        "agent-status",
        "agent-requests",
        "agent-answers",
    ),
    HOST: (
        "subscribe-all",
        "query-data",
        "worker-tokens",
        "worker-outputs",
        "worker-statuses",
        "not-provider-data",
        "host-token",
        "host-requests",
        "host-writes",
    ),
    APPLICATION: ("application-queries",),
    OPERATOR: ("application-queries", "store-requests"),
}
"""The rules of each fixed role (besides the common ones)."""


def _provider_rules(keys: KeySpace, provider: str) -> list[dict[str, Any]]:
    own = _provider_keys(keys, provider)
    return [
        # its own token, and one on each of its edges' data keys while the edge delivers
        _rule(f"provider-{provider}-token", ["liveliness_token"], [*own["token"], *own["data"]]),
        _rule(
            f"provider-{provider}-serves",
            SERVES,
            [*own["fragment"], *own["data"], keys.pattern("store", provider)],
        ),
        _rule(f"provider-{provider}-writes", WRITES, own["data"]),
    ]


def check_provider(provider: str) -> str:
    """``provider`` if it can name a provider certificate, else ``ValueError``."""
    validate_key_chunks(provider, single_chunk=True)
    if provider in ROLES:
        raise ValueError(f"{provider!r} is a role's common name, not a provider id")
    return provider


def access_control(keys: KeySpace, providers: Sequence[str]) -> dict[str, Any]:
    """Zenoh's ``access_control`` block for the roles above and the given provider ids."""
    providers = [check_provider(p) for p in providers]
    names = [*ROLES, *providers]
    provider_rules = {p: _provider_rules(keys, p) for p in providers}
    policies = [
        {
            "id": "everyone",
            "rules": ["receive", "liveliness", "subscribe", "read"],
            "subjects": names,
        },
        *({"id": role, "rules": list(ROLE_RULES[role]), "subjects": [role]} for role in ROLES),
        *(
            {"id": p, "rules": [r["id"] for r in rules], "subjects": [p]}
            for p, rules in provider_rules.items()
        ),
    ]
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": [
            *_common_rules(keys, providers),
            *_role_rules(keys, providers),
            *(r for rules in provider_rules.values() for r in rules),
        ],
        "subjects": [{"id": name, "cert_common_names": [name]} for name in names],
        "policies": policies,
    }
