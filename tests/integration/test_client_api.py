"""Provider and application APIs over real zenoh sessions on loopback."""

from __future__ import annotations

import itertools
import json
import threading
import time

import numpy as np
import pytest

from tests.integration.zenoh_helpers import free_port, hub_session, wait_until
from ubitrack_agent.core import ExtrapolationError, NoDataError, Pose, Position3D, decode, encode
from ubitrack_agent.io.application import Relation
from ubitrack_agent.io.provider import EdgeAnnouncement, Provider
from ubitrack_agent.net import config
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.session import open_session
from ubitrack_agent.net.transport import fetch_latest

pytestmark = pytest.mark.integration

MS = 1_000_000


def member(port: int):
    return open_session(
        config.Settings(connect=(f"tcp/127.0.0.1:{port}",), listen=("tcp/127.0.0.1:0",))
    )


def pose(t_ms: int, x: float) -> Pose:
    return Pose(t_ms * MS, [0, 0, 0, 1], [x, 0, 0])


def test_provider_announces_serves_fragment_and_latest_values():
    port = free_port()
    keys = KeySpace(f"ubitrack/p{port}")
    with hub_session(port) as hub, member(port) as sensor:
        events = []
        watcher = hub.liveliness().declare_subscriber(
            f"{keys.root}/provider/**", lambda s: events.append((str(s.kind), str(s.key_expr)))
        )
        edges = [
            EdgeAnnouncement("ART", "HT", "6D", rate=60.0, sigma=0.0005),
            EdgeAnnouncement("ART", "WT", "6D", static=True),
        ]
        with Provider(sensor, keys, "art1", edges) as provider:
            wait_until(lambda: ("SampleKind.PUT", keys.provider("art1")) in events)
            replies = fetch_latest(hub, keys.fragment("art1"))
            fragment = json.loads(replies[0])
            assert fragment["provider"] == "art1"
            assert fragment["edges"][0] == {
                "name": "ART_HT",
                "from": "ART",
                "to": "HT",
                "type": "6D",
                "static": False,
                "mode": "push",
                "sigma": 0.0005,
                "rate": 60.0,
            }
            assert fetch_latest(hub, keys.measured("art1", "ART_WT")) == []
            provider.publish("ART_WT", pose(1, 2.0))
            latest = wait_until(lambda: fetch_latest(hub, keys.measured("art1", "ART_WT")))
            assert decode(latest[0]) == pose(1, 2.0)
            with pytest.raises(TypeError, match="is 6D"):
                provider.publish("ART_HT", Position3D(1, [0, 0, 0]))
            with pytest.raises(KeyError):
                provider.publish("nope", pose(1, 0))
        wait_until(lambda: ("SampleKind.DELETE", keys.provider("art1")) in events)
        assert fetch_latest(hub, keys.fragment("art1"), timeout=0.2) == []
        watcher.undeclare()


def test_leaving_the_with_block_undeclares_provider_and_relation_even_on_error():
    port = free_port()
    keys = KeySpace(f"ubitrack/w{port}")
    wanted = RelationId("C", "A", "6D")
    with hub_session(port) as agent_side, member(port) as client:

        def alive() -> set[str]:
            return {
                str(reply.ok.key_expr)
                for reply in agent_side.liveliness().get(f"{keys.root}/**", timeout=0.5)
            }

        with (
            pytest.raises(RuntimeError, match="sensor failed"),
            Provider(client, keys, "cam1", [EdgeAnnouncement("C", "F1", "3D")]) as provider,
        ):
            assert wait_until(alive) == {keys.provider("cam1")}
            raise RuntimeError("sensor failed")
        wait_until(lambda: keys.provider("cam1") not in alive())
        provider.close()  # a second close does nothing

        with Relation(client, keys, wanted, application="app2", host="hmd") as relation:
            assert wait_until(alive) == {keys.query(wanted, "app2", "hmd")}
        wait_until(lambda: not alive())
        relation.close()


def test_a_provider_that_leaves_is_gone_at_once_and_its_last_samples_still_arrive():
    """``Provider.leave`` (what an adapter does first on SIGTERM) withdraws the token alone:
    the samples published after it still reach a subscriber, and closing after it is fine."""
    port = free_port()
    keys = KeySpace(f"ubitrack/l{port}")
    with hub_session(port) as hub, member(port) as sensor:
        events: list[str] = []
        watcher = hub.liveliness().declare_subscriber(
            keys.provider("art1"), lambda s: events.append(str(s.kind))
        )
        received: list[int] = []
        data = hub.declare_subscriber(
            keys.data("art1/ART_HT"),
            lambda s: received.append(decode(s.payload.to_bytes()).timestamp_ns),
        )
        edges = [EdgeAnnouncement("ART", "HT", "6D", rate=60.0)]
        with Provider(sensor, keys, "art1", edges) as provider:
            wait_until(lambda: events == ["SampleKind.PUT"])
            provider.leave()
            wait_until(lambda: events == ["SampleKind.PUT", "SampleKind.DELETE"])
            wait_until(lambda: provider.publish("ART_HT", pose(1, 0.1)) or received)
            provider.leave()  # a second leave does nothing
        assert events == ["SampleKind.PUT", "SampleKind.DELETE"]
        data.undeclare()
        watcher.undeclare()


def test_an_edge_token_says_while_the_edge_delivers():
    """The token on a dynamic edge's data key (``io.flowing``): declared with its first
    sample, withdrawn two and a half intervals after its last, or when the adapter says two
    frames in a row came without it (not one), declared again by its next sample, withdrawn
    when the provider leaves; a static edge has none."""
    port = free_port()
    keys = KeySpace(f"ubitrack/f{port}")
    with hub_session(port) as hub, member(port) as sensor:
        events: list[tuple[str, str]] = []
        watcher = hub.liveliness().declare_subscriber(
            f"{keys.root}/data/art1/**",
            lambda s: events.append((str(s.key_expr).rsplit("/", 1)[-1], str(s.kind)[11:])),
        )
        edges = [
            EdgeAnnouncement("ART", "HT", "6D", rate=60.0),
            EdgeAnnouncement("ART", "P", "6D", rate=60.0),
            EdgeAnnouncement("ART", "WT", "6D", static=True),
        ]
        with Provider(sensor, keys, "art1", edges) as provider:
            provider.publish("ART_WT", pose(0, 0.0))
            for i in range(6):
                provider.publish("ART_HT", pose(i + 1, 0.1))
                time.sleep(1 / 60)
            # silent: withdrawn by the provider's clock
            wait_until(lambda: events == [("ART_HT", "PUT"), ("ART_HT", "DELETE")])
            # one sample of P: its rate unknown, its clock never withdraws it; the frames do
            provider.publish("ART_P", pose(10, 0.1))
            wait_until(lambda: len(events) == 3)
            provider.missed("ART_P")  # one frame without it: a drop
            time.sleep(0.2)
            assert len(events) == 3
            provider.missed("ART_P")  # the second in a row
            wait_until(lambda: len(events) == 4)
            provider.publish("ART_P", pose(11, 0.1))
            wait_until(lambda: len(events) == 5)
            provider.leave()
            wait_until(lambda: len(events) == 6)
            with pytest.raises(KeyError):
                provider.missed("nope")
        assert events == [
            *[("ART_HT", "PUT"), ("ART_HT", "DELETE")],
            *[("ART_P", "PUT"), ("ART_P", "DELETE")] * 2,
        ]
        watcher.undeclare()


def test_leave_racing_publishers_leaves_no_edge_token():
    """``leave`` from one thread (a SIGTERM handler) while others publish and report missed
    frames on every edge: once it has returned no edge token is declared, none is declared
    again by later samples, and each edge's token went up and down in turn, ending down.
    Rounds with the leave early, midway and late in the burst."""
    port = free_port()
    keys = KeySpace(f"ubitrack/r{port}")
    names = [f"B{i}" for i in range(4)]
    edges = [EdgeAnnouncement("ART", name, "6D", rate=60.0) for name in names]
    with hub_session(port) as hub, member(port) as sensor:
        for round_, leave_after in enumerate((0.0, 0.05, 0.2)):
            provider_id = f"art{round_}"
            events: dict[str, list[str]] = {}
            lock = threading.Lock()

            def seen(sample, events=events, lock=lock) -> None:
                with lock:
                    edge = str(sample.key_expr).rsplit("_", 1)[-1]
                    events.setdefault(edge, []).append(str(sample.kind)[11:])

            watcher = hub.liveliness().declare_subscriber(
                f"{keys.root}/data/{provider_id}/**", seen
            )
            with Provider(sensor, keys, provider_id, edges) as provider:
                stop = threading.Event()

                def publish(name: str, provider=provider, stop=stop) -> None:
                    i = 0
                    while not stop.is_set():
                        i += 1
                        provider.publish(f"ART_{name}", pose(i, 0.1))
                        if i % 5 == 0:  # two frames without it: its token withdrawn
                            provider.missed(f"ART_{name}")
                            provider.missed(f"ART_{name}")
                        time.sleep(0.001)

                threads = [threading.Thread(target=publish, args=(n,)) for n in names]
                for thread in threads:
                    thread.start()
                try:
                    time.sleep(leave_after)
                    provider.leave()
                    time.sleep(0.1)  # the publishers go on after the leave
                finally:
                    stop.set()
                    for thread in threads:
                        thread.join()
                # an edge that published nothing before the leave never had a token
                declared = f"{keys.root}/data/{provider_id}/**"
                wait_until(lambda declared=declared: not list(hub.liveliness().get(declared)))
                wait_until(
                    lambda events=events: all(k[-1] == "DELETE" for k in list(events.values()))
                )
                time.sleep(0.2)  # nothing more comes
                assert list(hub.liveliness().get(declared)) == []
            watcher.undeclare()
            for name, kinds in events.items():
                assert name in names
                assert kinds[0] == "PUT" and kinds[-1] == "DELETE", (round_, name, kinds)
                assert all(a != b for a, b in itertools.pairwise(kinds)), (round_, name, kinds)


def test_bad_announcements_are_refused():
    with pytest.raises(ValueError):
        EdgeAnnouncement("A/B", "C", "6D")
    with pytest.raises(ValueError, match="edge type"):
        EdgeAnnouncement("A", "C", "7D")
    with pytest.raises(ValueError, match="mode"):
        EdgeAnnouncement("A", "C", "6D", mode="poll")
    with pytest.raises(ValueError, match="sigma"):
        EdgeAnnouncement("A", "C", "6D", sigma=-1.0)


def test_relation_announces_query_and_delivers_samples():
    port = free_port()
    keys = KeySpace(f"ubitrack/r{port}")
    wanted = RelationId("C", "A", "6D")
    with hub_session(port) as agent_side, member(port) as app_side:
        queries = []
        watcher = agent_side.liveliness().declare_subscriber(
            f"{keys.root}/query/**", lambda s: queries.append(str(s.key_expr))
        )
        seen = []
        with Relation(  # no agent here: the test publishes the relation itself
            app_side, keys, wanted, application="app1", callback=seen.append, keep_waiting=True
        ) as relation:
            wait_until(lambda: queries)
            host = config.default_host_name()
            assert keys.parse_query(queries[0]) == (wanted, "app1", host, frozenset())
            with pytest.raises(NoDataError):
                relation.lookup(0)
            with pytest.raises(TimeoutError):
                relation.wait_for(timeout=0.05)
            publisher = agent_side.declare_publisher(keys.relation(wanted))
            wait_until(lambda: publisher.matching_status.matching)
            waiter = threading.Thread(target=lambda: seen.append(("waited", relation.wait_for(5))))
            waiter.start()
            for t in (0, 10, 20):
                publisher.put(encode(pose(t, t / 10)))
            publisher.put(b"not a pose")
            publisher.put(encode(Position3D(30 * MS, [0, 0, 0])))  # wrong type for a 6D relation
            waiter.join(5)
            assert relation.get(timeout=5) == pose(0, 0.0)
            assert relation.get(timeout=5) == pose(10, 1.0)
            wait_until(lambda: relation.rejected == 2)
            assert relation.received == 3
            assert relation.latest() == pose(20, 2.0)
            np.testing.assert_allclose(relation.lookup(15 * MS).translation, [1.5, 0, 0])
            with pytest.raises(ExtrapolationError):
                relation.lookup(25 * MS)
            assert [s for s in seen if isinstance(s, Pose)] == [
                pose(0, 0),
                pose(10, 1),
                pose(20, 2),
            ]
            assert any(isinstance(s, tuple) and s[0] == "waited" for s in seen)
        watcher.undeclare()


def test_relation_gets_a_static_value_published_before_it_started():
    from ubitrack_agent.net.transport import LatestValuePublisher

    port = free_port()
    keys = KeySpace(f"ubitrack/s{port}")
    calibration = RelationId("C", "HT", "6D", static=True)
    with hub_session(port) as agent_side, member(port) as app_side:
        publisher = LatestValuePublisher(agent_side, keys.relation(calibration))
        publisher.put(encode(pose(5, 0.25)))
        with Relation(app_side, keys, calibration) as relation:
            assert wait_until(relation.latest) == pose(5, 0.25)
            assert relation.lookup(10**15).timestamp_ns == 10**15  # static: valid at any time
        publisher.undeclare()
