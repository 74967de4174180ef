"""What a command says while it waits for a relation (``ubitrack_agent/io/waiting.py``, issue
31): the progress line of a flow being started, where it looked for the agent."""

from __future__ import annotations

from types import SimpleNamespace

from tests.unit.test_worker_inputs import FakeSession
from ubitrack_agent.commands.subscribe import relation_types
from ubitrack_agent.graph.srg import EDGE_TYPES
from ubitrack_agent.io.waiting import StartWatch, network_of, starting
from ubitrack_agent.net.answer import Answer
from ubitrack_agent.net.config import Settings
from ubitrack_agent.net.keys import KeySpace, RelationId

KEYS = KeySpace("ubitrack/test")
ANNOUNCED = {"C", "A", "HT", "WT", "IP", "F1", "F2", "ART", "Marker1", "Marker2"}
C_A = RelationId("C", "A", "6D")


def test_the_progress_line_counts_the_planned_components_alive():
    served = Answer("C->A:6D", True, "k", None, {"fusion-1": "fusion", "inversion-2": "inversion"})
    assert starting(served, set()) == "planned: 2 components, 0 alive"
    assert starting(served, {"inversion-2", "other-9"}) == "planned: 2 components, 1 alive"
    one = Answer("C->A:6D", True, "k", None, {"fusion-1": "fusion"})
    assert starting(one, {"fusion-1"}) == "planned: 1 component, 1 alive"
    direct = Answer("C->A:6D", True, "k")
    assert starting(direct, set()) is None  # a measured edge: nothing to start
    assert starting(Answer("C->A:6D", False, "k", "no provider"), set()) is None
    assert starting(None, set()) is None
    stale = Answer("C->A:6D", False, "k", "waiting for data on art/HT (stale); ...", waiting=True)
    assert starting(stale, set()) == "waiting for data on art/HT (stale); ..."


def test_the_network_looked_at_is_named_by_endpoint_and_domain():
    hub = Settings(connect=("tcp/127.0.0.1:7448",), domain="lab")
    assert network_of(hub) == "tcp/127.0.0.1:7448/lab"
    assert network_of(Settings(listen=("tcp/0.0.0.0:7448",))) == "tcp/0.0.0.0:7448/default"
    two = Settings(connect=("tcp/a:7447", "tcp/b:7447"))
    assert network_of(two) == "tcp/a:7447 or tcp/b:7447/default"


def test_subscribe_checks_the_types_the_srg_has():
    """``subscribe`` checks ``--type`` without importing the graph layer: the same types."""
    assert relation_types() == sorted(EDGE_TYPES)


def token(instance: str, kind: str = "SampleKind.PUT", incarnation: str = "1.a") -> SimpleNamespace:
    return SimpleNamespace(key_expr=KEYS.worker(instance, incarnation), kind=kind)


def test_the_watch_reports_each_change_until_closed():
    session = FakeSession()
    lines: list[str] = []
    watch = StartWatch(session, KEYS, C_A, lines.append)
    workers = session.callbacks[KEYS.all_workers()]
    workers(token("other-9"))  # a worker of another flow, already running
    components = {"fusion-1": "fusion", "inversion-2": "inversion"}
    served = Answer(str(C_A), True, KEYS.relation(C_A), None, components)
    session.deliver(KEYS.answer(C_A), served.encode().encode())
    workers(token("fusion-1"))
    workers(token("fusion-1", incarnation="2.b"))  # restarted: the new token before the old goes
    workers(token("fusion-1", "SampleKind.DELETE"))
    workers(token("inversion-2"))
    workers(SimpleNamespace(key_expr="ubitrack/test/worker/bad key/1", kind="SampleKind.PUT"))
    session.deliver(KEYS.answer(C_A), b"{not json")
    assert lines == [
        "planned: 2 components, 0 alive",
        "planned: 2 components, 1 alive",
        "planned: 2 components, 2 alive",
    ]
    assert watch.counters["rejected"] == 2 and watch.counters["internal_errors"] == 0
    watch.close()
    watch.close()  # a second close does nothing
    assert KEYS.answer(C_A) not in session.callbacks and KEYS.all_workers() not in session.callbacks
