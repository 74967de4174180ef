"""Live fuzzing of the agent (issue 11): a real agent process serves ``WT->HT`` fused from two
exact trackers while hypothesis throws hostile input at every entry point it has on the
network: liveliness tokens of every kind with hostile names, provider fragments with hostile
values, shapes, nesting and sizes, application query keys, host exit reports and status
queries. Afterwards the agent is the same process, has failed no handler, still delivers the
true relation through fusion, and has counted the rejections. Bounded: well under a minute."""

from __future__ import annotations

import json
import math
import threading
import time

import pytest
import zenoh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.integration.test_agent import WT_HT, assert_true_pose, fresh_samples, setup  # noqa: F401
from tests.integration.zenoh_helpers import wait_until
from ubitrack_agent.core.names import check_name
from ubitrack_agent.graph.srg import EDGE_TYPES
from ubitrack_agent.io.application import Relation

pytestmark = pytest.mark.integration

EXAMPLES = 150
"""Examples per entry point (six of them): about 900 hostile messages in about ten seconds."""
COUNTERS = (
    "rejected_provider_keys",
    "rejected_query_keys",
    "rejected_worker_keys",
    "rejected_host_keys",
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


def invalid(name: str) -> bool:
    try:
        check_name(name)
    except ValueError:
        return True
    return False


HOSTILE_NAMES = st.sampled_from(
    ["*", "**", "a b", "a$*b", "Ä", "@x", "a/b", "x" * 2000, "a\nb", "\x00", "$*"]
) | st.text(max_size=30).filter(invalid)
GOOD_NAMES = st.from_regex(r"\Afz-[a-z0-9]{1,8}\Z")
HOSTILE_NUMBERS = st.sampled_from(
    [1e200, -1e200, 10**400, -(10**400), math.nan, math.inf, -math.inf, -1e-9, 1e6]
) | st.one_of(st.text(max_size=5), st.lists(st.integers(), max_size=3), st.booleans(), st.none())
"""Out of range for sigma, rate and latency alike (``graph.srg.QUALITY_BOUNDS``), or no number."""
NOT_A_WORD = st.text(max_size=8).filter(lambda text: text not in {"push", "pull", *EDGE_TYPES})
BASE_EDGE = {
    "name": "e",
    "from": "FZ1",
    "to": "FZ2",
    "type": "6D",
    "static": False,
    "mode": "push",
    "sigma": 0.001,
    "rate": 50.0,
}


def with_field(field: str, value) -> dict:
    return {**BASE_EDGE, field: value}


EDGES = st.one_of(
    st.builds(with_field, st.sampled_from(["sigma", "rate", "latency"]), HOSTILE_NUMBERS),
    st.builds(with_field, st.sampled_from(["name", "from", "to"]), HOSTILE_NAMES),
    st.builds(with_field, st.sampled_from(["type", "mode", "static"]), NOT_A_WORD),
    st.builds(with_field, st.sampled_from(["colour", "provider", "id"]), st.integers()),
)


def fragment(provider: str, edges: list) -> bytes:
    return json.dumps({"provider": provider, "edges": edges}).encode()


def hostile_fragment(provider: str) -> st.SearchStrategy[bytes]:
    """Fragments that must all be rejected, each hostile in one way."""
    many = [{**BASE_EDGE, "name": f"e{i}"} for i in range(1001)]
    return st.one_of(
        st.builds(lambda e: fragment(provider, [e]), EDGES),
        st.builds(lambda e: fragment(provider, [BASE_EDGE, e]), EDGES),
        st.just(fragment(provider, many)),
        st.just(fragment("someone-else", [BASE_EDGE])),
        st.just(fragment(provider, [])),
        st.just(b'{"provider": "' + provider.encode() + b'", "edges": ' + b"[" * 20000),
        st.just(b'{"provider": "p", "edges": [' + b"[" * 5000 + b"]" * 5000 + b"]}"),
        st.just(fragment(provider, [with_field("name", "n" * 300_000)])),
        st.just(b" " * (2 << 20)),
        st.binary(max_size=200),
        st.just(b'{"provider": 1' + b"0" * 5000 + b', "edges": []}'),
    )


class FragmentServer:
    """One queryable on every fragment key, answering the hostile providers' fragments."""

    def __init__(self, session, keys) -> None:
        self.payloads: dict[str, bytes] = {}
        self._prefix = keys.fragment("x")[:-1]
        self._queryable = session.declare_queryable(self._prefix + "*")
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        for query in self._queryable:
            with query:
                payload = self.payloads.get(str(query.key_expr)[len(self._prefix) :])
                if payload is not None:
                    query.reply(query.key_expr, payload)

    def close(self) -> None:
        self._queryable.undeclare()


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status", encoding="ascii") as status:
        line = next(line for line in status if line.startswith("VmRSS:"))
    return int(line.split()[1]) / 1024


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

        @FUZZ
        @given(kind=st.sampled_from(["provider", "worker", "host", "pool"]), name=HOSTILE_NAMES)
        def hostile_tokens(kind, name):
            declare(f"{root}/{kind}/{name}")

        @FUZZ
        @given(
            chunks=st.lists(
                st.one_of(HOSTILE_NAMES, st.sampled_from(["FZ1", "FZ2", "6D", "7D", "dynamic"])),
                min_size=1,
                max_size=7,
            )
        )
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
        @given(
            host=st.one_of(HOSTILE_NAMES, st.just("vm"), GOOD_NAMES),
            payload=st.one_of(
                st.binary(max_size=100),
                st.builds(
                    lambda obj: json.dumps(obj).encode(),
                    st.dictionaries(
                        st.sampled_from(["instance", "run", "pid", "reason"]),
                        st.text(max_size=5) | st.integers(),
                    ),
                ),
                st.just(b"[" * 20000),
            ),
        )
        def hostile_exit_reports(host, payload):
            try:
                session.put(f"{root}/host/{host}/exited", payload)
                sent["exit reports"] += 1
            except zenoh.ZError:
                sent["refused"] += 1

        @FUZZ
        @given(parameters=st.text(max_size=40), payload=st.binary(max_size=100))
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
    keys = [f"{root}/{kind}/{name}" for kind in ("worker", "provider", "host") for name in names]
    tokens = [session.liveliness().declare_token(key) for key in keys]
    tokens.append(session.liveliness().declare_token(setup.keys.provider("fz-sigma")))
    try:
        agent = setup.start_agent()
        setup.tracker("art", "ART", 30.0, 2.0)
        with Relation(session, setup.keys, WT_HT, application="app") as relation:
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
