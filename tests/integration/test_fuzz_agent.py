"""Live fuzzing of the agent (issue 11): a real agent process serves ``WT->HT`` fused from two
exact trackers while hypothesis throws hostile input at every entry point it has on the
network: liveliness tokens of every kind with hostile names, provider fragments with hostile
values, shapes, nesting and sizes, application query keys, host exit reports and status
queries. Afterwards the agent is the same process, has failed no handler, still delivers the
true relation through fusion, and has counted the rejections. Bounded: well under a minute."""

from __future__ import annotations

import time

import pytest
import zenoh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.integration.fuzz_inputs import (
    EXIT_REPORT_HOSTS,
    EXIT_REPORT_PAYLOADS,
    HOSTILE_NAMES,
    QUERY_CHUNKS,
    STATUS_PARAMETERS,
    STATUS_PAYLOADS,
    TOKEN_KINDS,
    FragmentServer,
    fragment,
    hostile_fragment,
    rss_mb,
    with_field,
)
from tests.integration.test_agent import WT_HT, assert_true_pose, fresh_samples, setup  # noqa: F401
from tests.integration.zenoh_helpers import wait_until
from ubitrack_agent.io.application import Relation

pytestmark = pytest.mark.integration

EXAMPLES = 150
"""Examples per entry point (six of them): about 900 hostile messages in about ten seconds."""
COUNTERS = (
    "rejected_provider_keys",
    "rejected_query_keys",
    "rejected_worker_keys",
    "rejected_host_keys",
    "rejected_agent_keys",
    "rejected_host_exited_keys",
    "rejected_host_reports",
    "rejected_announcements",
)
FUZZ = settings(
    max_examples=EXAMPLES,
    deadline=None,
    database=None,
    suppress_health_check=list(HealthCheck),
)


def test_hostile_input_on_every_entry_point_leaves_the_agent_serving(setup):  # noqa: F811
    agent = setup.start_agent()
    setup.tracker("art", "ART", 30.0, 2.0)
    setup.tracker("ir", "IR", 100.0, -1.0)
    relation = Relation(setup.session, setup.keys, WT_HT, application="app")
    session, root = setup.session, setup.keys.root
    server = FragmentServer(session, setup.keys)
    tokens: list = []
    sent = dict.fromkeys(("tokens", "fragments", "exit reports", "status queries", "refused"), 0)

    def declare(key: str) -> None:
        try:
            tokens.append(session.liveliness().declare_token(key))
            sent["tokens"] += 1
        except zenoh.ZError:
            sent["refused"] += 1  # not a key expression zenoh takes: nothing reaches the agent

    try:
        wait_until(lambda: "fusion" in setup.alive_services().values(), timeout=30)
        before = setup.status()["counters"]
        rss_before = rss_mb(agent.pid)

        def token_key(kind: str, name: str) -> str:
            # A worker's token has two chunks (<instance>/<incarnation>): the agent listens on
            # worker/*/*, so a one-chunk one never reaches it (and was not counted).
            return f"{root}/{kind}/{name}/1.x" if kind == "worker" else f"{root}/{kind}/{name}"

        for kind in ("provider", "worker", "host", "agents"):  # one of each kind for sure
            declare(token_key(kind, "a b"))

        @FUZZ
        @given(kind=TOKEN_KINDS, name=HOSTILE_NAMES)
        def hostile_tokens(kind, name):
            declare(token_key(kind, name))

        @FUZZ
        @given(chunks=QUERY_CHUNKS)
        def hostile_queries(chunks):
            declare(f"{root}/query/{'/'.join(chunks)}")

        @FUZZ
        @given(data=st.data())
        def hostile_providers(data):
            name = f"fz-{len(server.payloads)}"  # a fresh provider for every example
            server.payloads[name] = data.draw(hostile_fragment(name))
            declare(setup.keys.provider(name))
            sent["fragments"] += 1

        @FUZZ
        @given(host=EXIT_REPORT_HOSTS, payload=EXIT_REPORT_PAYLOADS)
        def hostile_exit_reports(host, payload):
            try:
                session.put(f"{root}/host/{host}/exited", payload)
                sent["exit reports"] += 1
            except zenoh.ZError:
                sent["refused"] += 1

        @FUZZ
        @given(parameters=STATUS_PARAMETERS, payload=STATUS_PAYLOADS)
        def hostile_status_queries(parameters, payload):
            try:
                replies = session.get(
                    f"{setup.keys.agent_status()}?{parameters}", payload=payload, timeout=0.2
                )
                list(replies)
                sent["status queries"] += 1
            except zenoh.ZError:
                sent["refused"] += 1

        started = time.monotonic()
        for fuzz in (
            hostile_tokens,
            hostile_queries,
            hostile_providers,
            hostile_exit_reports,
            hostile_status_queries,
        ):
            fuzz()
        half = len(tokens) // 2
        for token in tokens[:half]:  # half of them go again: DELETE events too
            token.undeclare()
        del tokens[:half]
        print(f"sent {sent} in {time.monotonic() - started:.1f} s")

        fuzzed = set(server.payloads)
        status = wait_until(
            lambda: (s := setup.status()) and fuzzed <= set(s["rejected_providers"]) and s,
            timeout=20,
        )
        after = status["counters"]
        print(f"counters {after}; RSS {rss_before:.0f} -> {rss_mb(agent.pid):.0f} MB")
        assert agent.poll() is None  # the same agent process
        assert not [name for name in after if name.startswith("failed_")], status["problems"]
        moved = [name for name in COUNTERS if after.get(name, 0) > before.get(name, 0)]
        assert moved == list(COUNTERS)
        assert not set(status["providers"]) & fuzzed
        assert "fusion" in setup.alive_services().values()  # both trackers still fused
        for sample in fresh_samples(relation, 20):
            assert_true_pose(sample)
        assert rss_mb(agent.pid) < rss_before + 200
    finally:
        for token in tokens:
            token.undeclare()
        server.close()
        relation.close()


def test_an_agent_started_among_hostile_tokens_keeps_running(setup):  # noqa: F811
    """A restarted agent reads the tokens already there (liveliness history): hostile ones
    must not make it crash-loop (issue 11: it died again within 6 s while the token existed)."""
    session, root = setup.session, setup.keys.root
    server = FragmentServer(session, setup.keys)
    server.payloads["fz-sigma"] = fragment("fz-sigma", [with_field("sigma", 1e200)])
    names = ["*", "**", "a b", "a$*b", "Ä"]
    # a worker's token is <root>/worker/<instance>/<incarnation>: hostile instance names there
    keys = [f"{root}/worker/{name}/1.x" for name in names]
    keys += [f"{root}/{kind}/{name}" for kind in ("provider", "host") for name in names]
    tokens = [session.liveliness().declare_token(key) for key in keys]
    tokens.append(session.liveliness().declare_token(setup.keys.provider("fz-sigma")))
    try:
        agent = setup.start_agent()
        setup.tracker("art", "ART", 30.0, 2.0)
        with Relation(  # asked while the tracker starts
            session, setup.keys, WT_HT, application="app", keep_waiting=True
        ) as relation:
            for sample in fresh_samples(relation, 10, timeout=30):
                assert_true_pose(sample)
        status = setup.status()
        assert agent.poll() is None
        assert "fz-sigma" in status["rejected_providers"]
        for kind in ("worker", "provider", "host"):
            assert status["counters"][f"rejected_{kind}_keys"] >= len(names)
    finally:
        for token in tokens:
            token.undeclare()
        server.close()
