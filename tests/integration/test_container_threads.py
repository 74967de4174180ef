"""The threads of a real container process do not grow with its components (issue 28): every
output key's publisher shares the process's answering threads (``net.transport.ANSWERS``) and
zenoh's own thread for its queryable and matching listener, where it had two threads of its
own. Counted from outside, in ``/proc/<pid>/task``."""

from __future__ import annotations

import json
import os
import time

import pytest

from tests.integration.test_container import start_container
from tests.integration.test_worker import query_status, random_pose
from tests.integration.zenoh_helpers import Collector, free_port, hub_session, wait_until
from ubitrack_agent.core import decode, encode
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.spec import ComponentSpec, GroupSpec, InputBinding
from ubitrack_agent.net.time_queries import fetch_at
from ubitrack_agent.net.transport import ANSWERING_THREADS, LatestValuePublisher

pytestmark = pytest.mark.integration

PUT = "SampleKind.PUT"
ADDED = 20
"""Components added to the running container: at two threads per output key before, 40 more."""


def link(keys: KeySpace, k: int) -> ComponentSpec:
    """Component ``k`` of a chain of concatenations: the first reads the provider over zenoh,
    each next one the previous one's output in the process; each a static edge of its own."""
    source = keys.data("provider/HT") if k == 0 else keys.data(f"c{k - 1}/AC")
    return ComponentSpec(
        instance=f"c{k}",
        service="concatenation",
        inputs=(
            InputBinding("AB", keys.data(f"static/{k}"), static=True),
            InputBinding("BC", source, trigger=True, from_worker=k > 0),
        ),
        outputs={"AC": keys.data(f"c{k}/AC")},
    )


def threads(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/task"))


def settled_threads(pid: int, seconds: float = 1.5) -> int:
    """The process's thread count once it has stayed the same for ``seconds``."""
    count, since = threads(pid), time.monotonic()
    deadline = since + 20.0
    while time.monotonic() - since < seconds and time.monotonic() < deadline:
        time.sleep(0.1)
        now = threads(pid)
        if now != count:
            count, since = now, time.monotonic()
    return count


def test_a_container_holds_as_many_threads_with_22_components_as_with_2(processes):
    port = free_port()
    domain = f"t{port}"
    keys = KeySpace(f"ubitrack/{domain}")
    group = GroupSpec("box", (link(keys, 0), link(keys, 1)))
    with hub_session(port) as session:
        statics = [
            LatestValuePublisher(session, keys.data(f"static/{k}")) for k in range(2 + ADDED)
        ]
        for k, static in enumerate(statics):
            static.put(encode(random_pose(100 + k)))
        container = start_container(processes, group, port, domain)
        provider = session.declare_publisher(keys.data("provider/HT"))
        wait_until(lambda: provider.matching_status.matching, timeout=30)

        def alive(instance: str) -> bool:
            """Whether ``instance``'s liveliness token is up (it takes commands and queries)."""
            return any(r.ok for r in session.liveliness().get(keys.worker_tokens(instance)))

        def flows_to(last: int, t: int) -> None:
            """A provider's sample runs down the chain to component ``last``'s output key, read
            here (a subscriber outside: zenoh carries it), and a time query to that key is
            answered by the container (one of its answering threads)."""
            wait_until(lambda: alive(f"c{last}"), timeout=30)
            end = Collector(session, keys.data(f"c{last}/AC"))
            wait_until(lambda: query_status(session, keys, f"c{last}")["counters"]["buffered"])
            provider.put(encode(random_pose(t)))
            while decode(end.next()).timestamp_ns != t:
                pass
            answer = decode(fetch_at(session, keys.data(f"c{last}/AC"), t, timeout=5.0))
            assert answer.timestamp_ns == t
            end.subscriber.undeclare()

        flows_to(1, 1_000)
        two = settled_threads(container.pid)

        added = [link(keys, k) for k in range(2, 2 + ADDED)]
        session.put(keys.control("box"), json.dumps({"add": [s.as_dict() for s in added]}))
        flows_to(1 + ADDED, 2_000)
        many = settled_threads(container.pid)
        box = query_status(session, keys, "box")
        assert len(box["components"]) == 2 + ADDED
        print(f"threads of the container: {two} with 2 components, {many} with {2 + ADDED}")
        # Independent of the components: at most the answering threads the pool may have
        # started meanwhile (queries come at once); two a component's output key before.
        assert many - two <= ANSWERING_THREADS - 1
        for static in statics:
            static.undeclare()
