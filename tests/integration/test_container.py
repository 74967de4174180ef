"""A real container process (``ubitrack_agent.services.container``) with real zenoh sessions: two
components wired in the process, one reading a provider over zenoh, the application's relation on
zenoh; a component added and removed in the running process; malformed input to one component leaves
the other running; SIGTERM ends it cleanly."""

from __future__ import annotations

import json
import signal
import subprocess
import sys

import numpy as np
import pytest

from tests.integration.test_worker import query_status, random_pose
from tests.integration.zenoh_helpers import (
    Collector,
    free_port,
    hub_session,
    member_flags,
    wait_until,
)
from ubitrack_agent.core import Pose, decode, encode
from ubitrack_agent.core.poses import compose_poses, invert_pose
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.spec import ComponentSpec, GroupSpec, InputBinding

pytestmark = pytest.mark.integration

PUT = "SampleKind.PUT"


def close(result: Pose, want: Pose) -> bool:
    return bool(
        np.allclose(result.translation, want.translation, atol=1e-12)
        and abs(abs(np.dot(result.rotation, want.rotation)) - 1) < 1e-12
    )


def start_container(processes, group: GroupSpec, port: int, domain: str) -> subprocess.Popen:
    """A container process running ``group``, joined to the test's hub (ended by the
    ``processes`` fixture)."""
    container = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "ubitrack_agent.services.container",
            "--group",
            group.to_json(),
            *member_flags(port, domain),
        ],
        start_new_session=True,
    )
    processes.append(container)
    return container


def test_a_container_wires_in_the_process_adds_removes_and_contains_bad_input(processes):
    port = free_port()
    domain = f"c{port}"
    keys = KeySpace(f"ubitrack/{domain}")
    relation = keys.relation(RelationId("World", "Tool", "6D"))
    first = ComponentSpec(
        instance="first",
        service="concatenation",
        inputs=(
            InputBinding("AB", keys.data("ART/WT"), static=True),
            InputBinding("BC", keys.data("ART/HT"), trigger=True),
        ),
        outputs={"AC": keys.data("first/AC")},
    )
    second = ComponentSpec(
        instance="second",
        service="concatenation",
        inputs=(
            InputBinding("AB", keys.data("CAL/X"), static=True),
            InputBinding("BC", keys.data("first/AC"), trigger=True, from_worker=True),
        ),
        outputs={"AC": keys.data("second/AC")},
        relations={"AC": (relation,)},
    )
    group = GroupSpec("box0", (first, second))
    with hub_session(port) as session:
        tokens: dict[str, list[str]] = {"first": [], "second": [], "third": []}
        watchers = [
            session.liveliness().declare_subscriber(
                keys.worker_tokens(name),
                lambda s, name=name: tokens[name].append(str(s.kind)),
                history=True,
            )
            for name in tokens
        ]
        application = Collector(session, relation)
        container = start_container(processes, group, port, domain)
        wait_until(lambda: PUT in tokens["first"] and PUT in tokens["second"], timeout=30)
        wt, cal, ht = (
            session.declare_publisher(keys.data(k)) for k in ("ART/WT", "CAL/X", "ART/HT")
        )
        wait_until(lambda: all(p.matching_status.matching for p in (wt, cal, ht)))

        # 1. one process; the provider's data over zenoh, the wire between the two in the process
        statuses = {name: query_status(session, keys, name) for name in ("first", "second")}
        assert {s["pid"] for s in statuses.values()} == {container.pid}
        assert {s["container"] for s in statuses.values()} == {"box0"}
        box = query_status(session, keys, "box0")
        assert set(box["components"]) == {"first", "second"} and box["wires"] == 1
        static, calibration = random_pose(1_000), random_pose(1_000)
        wt.put(encode(static))
        cal.put(encode(calibration))
        wait_until(
            lambda: (
                query_status(session, keys, "second")["counters"]["buffered"] == 1
                and query_status(session, keys, "first")["counters"]["buffered"] == 1
            )
        )
        for i in range(5):
            moving = random_pose(2_000 + i)
            ht.put(encode(moving))
            result = decode(application.next())
            assert result.timestamp_ns == moving.timestamp_ns
            assert close(result, compose_poses(calibration, compose_poses(static, moving)))
        counters = query_status(session, keys, "first")["counters"]
        assert counters["published"] == counters["handed_over"] == counters["not_sent"] == 5

        # 2. a reader outside the process appears: zenoh carries first's output to it too
        outside = Collector(session, keys.data("first/AC"))
        assert decode(outside.next()).timestamp_ns == 2_004  # the latest, sent when it appeared
        current = random_pose(3_000)
        ht.put(encode(current))
        assert decode(outside.next()).timestamp_ns == 3_000
        assert decode(application.next()).timestamp_ns == 3_000
        outside.subscriber.undeclare()

        # 3. a component added to the running process reads first's output there; removed again
        third = ComponentSpec(
            instance="third",
            service="inversion",
            inputs=(InputBinding("AB", keys.data("first/AC"), trigger=True, from_worker=True),),
            outputs={"BA": keys.data("third/BA")},
        )
        inverted = Collector(session, keys.data("third/BA"))
        session.put(keys.control("box0"), json.dumps({"add": [third.as_dict()]}))
        wait_until(lambda: PUT in tokens["third"])
        # it is handed first's current value at once (no wait for the next sample)
        result = decode(inverted.next())
        assert close(result, invert_pose(compose_poses(static, current)))
        moving = random_pose(4_000)
        ht.put(encode(moving))
        result = decode(inverted.next())
        assert close(result, invert_pose(compose_poses(static, moving)))
        assert query_status(session, keys, "third")["pid"] == container.pid
        session.put(keys.control("box0"), json.dumps({"remove": ["third"]}))
        wait_until(lambda: "SampleKind.DELETE" in tokens["third"])
        # (its token goes as its run ends; the container counts it once the run has ended)
        box = wait_until(
            lambda: (b := query_status(session, keys, "box0"))["counters"]["removed"] and b
        )
        assert set(box["components"]) == {"first", "second"}
        assert (box["counters"]["added"], box["counters"]["removed"]) == (3, 1)

        # 4. malformed input to one component: counted there, the other goes on
        for bad in (b"garbage", b"\x81\xa1v\x01", encode(random_pose(5_000))[:-3]):
            cal.put(bad)
        session.put(keys.control("box0"), b"{not json")
        wait_until(lambda: query_status(session, keys, "second")["counters"]["rejected"] == 3)
        application.drain()
        for i in range(3):
            ht.put(encode(random_pose(6_000 + i)))
            assert decode(application.next()).timestamp_ns == 6_000 + i
        assert query_status(session, keys, "first")["counters"]["rejected"] == 0
        box = query_status(session, keys, "box0")
        assert box["counters"]["rejected_commands"] == 1 and box["counters"]["restarts"] == 0

        # 5. SIGTERM: clean exit, every component's token gone
        container.send_signal(signal.SIGTERM)
        assert container.wait(timeout=10) == 0
        wait_until(lambda: all("SampleKind.DELETE" in tokens[name] for name in ("first", "second")))
        for watcher in watchers:
            watcher.undeclare()
