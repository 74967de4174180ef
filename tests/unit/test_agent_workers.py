"""The agent's view of worker processes (``agent/runtime.py``) without a session: token events
matched to the incarnation that declared them, duplicates stopped one process at a time
(regression tests of the chaos run of issue 11), and rewires that wait for the new workers."""

from __future__ import annotations

from collections import Counter, defaultdict
from types import SimpleNamespace

from ubitrack_agent.agent.hosts import Placement
from ubitrack_agent.agent.runtime import REROUTE_S, RETIRE_S, Agent
from ubitrack_agent.agent.stamps import Stamps
from ubitrack_agent.net.host_protocol import STOP_COMMAND
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.spec import HAND_OVER_HOLD_S, STANDBY_S, ComponentSpec

KEYS = KeySpace("ubitrack/test")
CONCAT = ComponentSpec("fused", "concatenation", (), {"AC": "ubitrack/test/data/fused/AC"})


def agent(placements: dict[str, Placement] | None = None) -> tuple[Agent, list]:
    """An agent's worker bookkeeping alone, with the puts it makes."""
    puts: list[tuple[str, str]] = []
    bare = Agent.__new__(Agent)
    bare.keys = KEYS
    bare.counters = Counter()
    bare.alive = set()
    bare.incarnations = defaultdict(dict)
    bare.running = {}
    bare._stopped = {}
    bare._duplicate_stops = {}
    bare._held = {}
    bare._retiring = {}
    bare._standby = set()
    bare._unwanted_since = {}
    bare._all_alive_since = None
    bare._unrouted = {}
    bare.wanted = {}
    bare.stamps = Stamps()
    placed = dict(placements or {})
    bare.hosts = SimpleNamespace(placements=placed, reports_exit_of=lambda i: i in placed)
    bare.session = SimpleNamespace(put=lambda key, payload, **_: puts.append((key, payload)))
    return bare, puts


def test_a_late_removal_of_an_earlier_process_token_leaves_the_current_one_alive():
    bare, _ = agent()
    bare.running["concat-1"] = "spec"
    bare._on_worker("concat-1", "100.aaaa", appeared=True)
    bare._on_worker("concat-1", "200.bbbb", appeared=True)  # started again
    bare._on_worker("concat-1", "100.aaaa", appeared=False)  # the old token's late removal
    assert "concat-1" in bare.alive and bare.running == {"concat-1": "spec"}
    assert bare.counters["earlier_incarnation_removals"] == 1
    assert bare.counters["restarts"] == 0
    bare._on_worker("concat-1", "200.bbbb", appeared=False)  # now it is gone
    assert "concat-1" not in bare.alive
    bare._unrouted["concat-1"] = 0.0  # REROUTE_S is over: its token did not come back
    bare._restart_unrouted()
    assert bare.counters["restarts"] == 1 and "concat-1" not in bare.running


def test_a_worker_back_within_the_reroute_time_is_not_started_again(monkeypatch):
    """Its host manager died and it was that manager's client: its token vanishes, then comes
    back through the hub (``REROUTE_S``); it keeps running, adopted as it is."""
    clock = [50.0]
    monkeypatch.setattr("ubitrack_agent.agent.runtime.time.monotonic", lambda: clock[0])
    bare, _ = agent()
    bare.running["concat-1"] = "spec"
    bare._on_worker("concat-1", "100.aaaa", appeared=True)
    bare._on_worker("concat-1", "100.aaaa", appeared=False)
    clock[0] += REROUTE_S / 2
    bare._restart_unrouted()
    assert bare.running == {"concat-1": "spec"}  # not yet
    bare._on_worker("concat-1", "100.aaaa", appeared=True)  # declared again, through the hub
    clock[0] += REROUTE_S
    bare._restart_unrouted()
    assert bare.running == {"concat-1": "spec"} and bare.counters["restarts"] == 0
    assert bare._unrouted == {}


def test_a_duplicate_is_stopped_alone_keeping_the_placed_process():
    bare, puts = agent({"concat-1": Placement("lab", "run-1", 200)})
    bare._on_worker("concat-1", "100.aaaa", appeared=True)  # an earlier agent's, still starting
    bare._on_worker("concat-1", "200.bbbb", appeared=True)  # the one the host manager placed
    bare._stop_duplicates()
    assert puts == [(KEYS.control_incarnation("concat-1", "100.aaaa"), STOP_COMMAND)]
    bare._stop_duplicates()  # not again before STOP_RESEND_S
    assert len(puts) == 1


def test_without_a_placement_the_process_seen_first_is_kept():
    bare, puts = agent()
    bare._on_worker("concat-1", "300.cccc", appeared=True)
    bare._on_worker("concat-1", "100.aaaa", appeared=True)
    bare._stop_duplicates()
    assert puts == [(KEYS.control_incarnation("concat-1", "100.aaaa"), STOP_COMMAND)]


def test_a_rewire_decided_with_starts_waits_until_the_new_workers_are_alive(monkeypatch):
    """Regression (churn benchmark): a relation moved at once to a fusion still starting cold
    was silent for 2-7 s. A rewire of relation routes waits ``HAND_OVER_HOLD_S`` longer: the
    new producer takes the key over once its estimate is ready (services.handover)."""
    clock = [50.0]
    monkeypatch.setattr("ubitrack_agent.agent.runtime.time.monotonic", lambda: clock[0])
    bare, puts = agent()
    bare.running = {"fusion-old": "spec", "fusion-new": "spec"}
    bare.wanted = {"fusion-old": "spec", "fusion-new": "spec"}
    bare.alive = {"fusion-old"}
    bare._rewire("fusion-old", {"relations": {}}, wait=True)  # fusion-new takes the relation
    bare._rewire("fusion-old", {"inputs": []}, wait=False)  # a later change merges with it
    bare._retire()
    assert puts == []  # the old producer keeps publishing while the new one starts
    bare.alive.add("fusion-new")
    bare._retire()
    assert puts == []  # the new producer's estimate may not be ready yet
    clock[0] += HAND_OVER_HOLD_S
    bare._retire()
    assert puts == [(KEYS.control("fusion-old"), '{"relations": {}, "inputs": []}')]
    assert bare.counters["held_rewires"] == 1 and bare._held == {}


def test_a_replaced_worker_runs_on_until_the_new_producer_could_take_its_key(monkeypatch):
    clock = [50.0]
    monkeypatch.setattr("ubitrack_agent.agent.runtime.time.monotonic", lambda: clock[0])
    bare, _ = agent()
    bare.wanted, bare.alive = {"fusion-new": "spec"}, {"camera-only"}
    bare._retiring = {"camera-only": clock[0] + 10.0}
    stopped: list[str] = []
    bare._stop_worker = stopped.append
    bare._retire()  # the new flow is still starting
    bare.alive.add("fusion-new")
    clock[0] += 0.1
    bare._retire()
    clock[0] += HAND_OVER_HOLD_S * 0.9
    bare._retire()
    assert stopped == []  # the old flow keeps the key while the new one converges
    clock[0] += HAND_OVER_HOLD_S * 0.1
    bare._retire()
    assert stopped == ["camera-only"] and bare._retiring == {}


def test_a_standby_worker_outlives_the_hand_over_and_is_adopted_when_wanted_again(monkeypatch):
    """The old flow of a relation that lost a sensor (``agent.standby``) runs on after the new
    one has taken the key, until ``STANDBY_S``; planned again meanwhile (the sensor is back),
    it is adopted, not started."""
    clock = [50.0]
    monkeypatch.setattr("ubitrack_agent.agent.runtime.time.monotonic", lambda: clock[0])
    bare, puts = agent()
    bare.wanted, bare.alive = {"camera-only": CONCAT}, {"camera-only", "fused", "old"}
    bare._retiring = {"fused": clock[0] + STANDBY_S, "old": clock[0] + RETIRE_S}
    bare._standby = {"fused"}
    stopped: list[str] = []
    bare._stop_worker = stopped.append
    bare._retire()
    clock[0] += HAND_OVER_HOLD_S
    bare._retire()
    assert stopped == ["old"] and bare._standby == {"fused"}  # handed over: only "old" goes
    bare.alive.discard("old")  # its process ended
    bare.running = {"camera-only": CONCAT}  # retiring now, stopped after its own hand-over
    bare.wanted = {"fused": CONCAT}  # the sensor is back: the same derivation is planned
    bare._claim_unknown_workers()
    assert bare.running["fused"] == CONCAT and bare._standby == set()
    assert bare._retiring == {} and [key for key, _ in puts] == [KEYS.control("fused")]
    assert bare.counters["adopted"] == 0  # its own worker taken back, not an earlier agent's


def test_a_standby_worker_not_wanted_again_is_stopped_after_standby_s(monkeypatch):
    clock = [50.0]
    monkeypatch.setattr("ubitrack_agent.agent.runtime.time.monotonic", lambda: clock[0])
    bare, _ = agent()
    bare.wanted, bare.alive = {"camera-only": CONCAT}, {"camera-only", "fused"}
    bare._retiring, bare._standby = {"fused": clock[0] + STANDBY_S}, {"fused"}
    stopped: list[str] = []
    bare._stop_worker = stopped.append
    bare._retire()
    clock[0] += STANDBY_S - 0.01
    bare._retire()
    assert stopped == []
    clock[0] += 0.02
    bare._retire()
    assert stopped == ["fused"] and bare._standby == set() and bare._retiring == {}


def test_a_held_rewire_of_a_worker_that_ended_is_dropped():
    bare, puts = agent()
    bare.running = {"concat-1": "spec"}
    bare._rewire("concat-1", {"inputs": []}, wait=True)
    bare._on_worker("concat-1", "100.aaaa", appeared=True)
    bare._on_worker("concat-1", "100.aaaa", appeared=False)  # it vanished
    bare._retire()
    assert puts == []  # not sent to a worker that is not alive
    bare._unrouted["concat-1"] = 0.0  # and it did not come back: started afresh
    bare._restart_unrouted()
    bare._retire()
    assert puts == [] and bare._held == {}


def test_only_a_worker_nothing_ran_asks_for_its_relations_to_be_planned_again():
    bare, _ = agent()
    bare.running["concat-1"] = "spec"
    assert not bare._on_worker("concat-1", "100.aaaa", appeared=True)  # started by this agent
    assert bare._on_worker("fusion-2", "300.cccc", appeared=True)  # an earlier agent's
    assert not bare._on_worker("fusion-2", "400.dddd", appeared=True)  # alive already
    assert not bare._on_worker("fusion-2", "300.cccc", appeared=False)
