"""Messages that name another key than the one they came on are refused (``net.address``).

Zenoh delivered other keys' messages on a machine's subscriptions right after a partition
longer than its lease (``tests/integration/test_hosts_netns.py``). That cannot be caused on
purpose, so these tests put what such a delivery looks like: a message on one key whose
attachment names another. A real worker process and an application's relation refuse it,
count it, and take the messages that name their key as before.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.integration.test_worker import expected, query_status, random_pose, start_worker
from tests.integration.zenoh_helpers import Collector, free_port, hub_session, wait_until
from ubitrack_agent.core import Pose, decode, encode, se3
from ubitrack_agent.io.application import Relation
from ubitrack_agent.net.address import tag
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.sequence import Numbering
from ubitrack_agent.net.spec import ComponentSpec, InputBinding

pytestmark = pytest.mark.integration

MS = 1_000_000


def test_a_worker_refuses_samples_and_commands_put_on_another_key(processes):
    port = free_port()
    domain = f"m{port}"
    keys = KeySpace(f"ubitrack/{domain}")
    spec = ComponentSpec(
        instance="concat",
        service="concatenation",
        inputs=(
            InputBinding("AB", keys.data("ART/WT"), static=True),
            InputBinding("BC", keys.data("ART/HT"), trigger=True),
        ),
        outputs={"AC": keys.data("concat/AC")},
    )
    with hub_session(port) as session:
        output = Collector(session, keys.data("concat/AC"))
        worker = start_worker(processes, spec, port, domain, session, keys)
        wt = session.declare_publisher(keys.data("ART/WT"))
        ht = session.declare_publisher(keys.data("ART/HT"))
        wait_until(lambda: wt.matching_status.matching and ht.matching_status.matching)
        static = random_pose(1_000)
        wt.put(encode(static), attachment=Numbering(keys.data("ART/WT")).next())
        own, other = Numbering(keys.data("ART/HT")), Numbering(keys.data("ART/XT"))

        # A sample of another key, delivered on the trigger's: no output at its instant.
        ht.put(encode(random_pose(2_000)), attachment=other.next())
        # A stop meant for another component, delivered on this one's control key.
        session.put(
            keys.control("concat"),
            json.dumps({"stop": True}),
            attachment=tag(keys.control("other")),
        )
        moving = random_pose(3_000)
        ht.put(encode(moving), attachment=own.next())
        result = decode(output.next())
        assert result.timestamp_ns == 3_000
        np.testing.assert_allclose(
            se3.to_matrix(result.rotation, result.translation), expected(static, moving), atol=1e-12
        )
        counters = wait_until(
            lambda: (
                (c := query_status(session, keys, "concat")["counters"])["misaddressed"] == 2 and c
            )
        )
        assert counters["published"] == 1 and counters["rejected_commands"] == 0
        assert worker.poll() is None  # the stop meant for another did not stop it

        # A stop that names its key stops it.
        session.put(
            keys.control("concat"),
            json.dumps({"stop": True}),
            attachment=tag(keys.control("concat")),
        )
        assert worker.wait(timeout=10) == 0


def test_an_application_refuses_samples_put_on_another_relation_key():
    port = free_port()
    keys = KeySpace(f"ubitrack/a{port}")
    wanted = RelationId("C", "A", "6D")
    elsewhere = keys.relation(RelationId("C", "HT", "6D"))
    with (
        hub_session(port) as session,
        Relation(session, keys, wanted, application="app", keep_waiting=True) as relation,
    ):
        publisher = session.declare_publisher(keys.relation(wanted))
        wait_until(lambda: publisher.matching_status.matching)
        own, other = Numbering(keys.relation(wanted)), Numbering(elsewhere)
        far_off = Pose(10 * MS, [0, 0, 0, 1], [2.0, 0, 0])  # another relation's value
        publisher.put(encode(far_off), attachment=other.next())
        right = Pose(20 * MS, [0, 0, 0, 1], [0.1, 0, 0])
        publisher.put(encode(right), attachment=own.next())
        assert relation.get(timeout=5) == right
        wait_until(lambda: relation.counters["misaddressed"] == 1)
        assert relation.received == 1 and relation.counters["missed"] == 0
