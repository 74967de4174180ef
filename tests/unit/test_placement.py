"""Placement of workers on hosts (``ubitrack_agent/agent/placement.py``): near their data, the
last hop beside the application, labels and capacity respected, no flapping."""

import pytest

from ubitrack_agent.agent.placement import (
    DOWNSTREAM_WEIGHT,
    LOAD_WEIGHT,
    MOVE_MARGIN,
    group_containers,
    place,
)
from ubitrack_agent.net.host_protocol import HostInfo
from ubitrack_agent.net.spec import ComponentSpec, InputBinding

ROOM, HMD = HostInfo("room"), HostInfo("hmd")
CAMERA_FEATURES, CAMERA_INTRINSICS = "d/cam/IF", "d/store/CI"
ART_HT, MARKERS = "d/art/ART_HT", "d/store/OF"


def spec(instance, *inputs, static=(), relations=()):
    return ComponentSpec(
        instance=instance,
        service="x",
        inputs=tuple(
            InputBinding(f"p{i}", key, static=key in static) for i, key in enumerate(inputs)
        ),
        outputs={"out": f"d/{instance}/out"},
        relations={"out": tuple(relations)} if relations else {},
    )


# The paper's figure 1 split over two machines: the camera on the HMD's computer, the A.R.T.
# tracker and the calibration store on the room's.
DATA_HOSTS = {CAMERA_FEATURES: "hmd", CAMERA_INTRINSICS: "room", ART_HT: "room", MARKERS: "room"}
STATICS = (CAMERA_INTRINSICS, MARKERS)


def figure1(relations=("rel/C/A",)):
    pnp = spec("pnp", CAMERA_INTRINSICS, CAMERA_FEATURES, MARKERS, static=STATICS)
    concat = spec("concat", "d/pnp/out", ART_HT, relations=relations)
    return {"pnp": pnp, "concat": concat}


def test_pose_estimation_runs_beside_its_camera():
    placement = place(figure1(), {"room": ROOM, "hmd": HMD}, DATA_HOSTS, {})
    assert placement.hosts["pnp"] == "hmd"  # features stream locally; two statics cross
    assert placement.unplaced == {}


@pytest.mark.parametrize(("application", "expected"), [("hmd", "hmd"), ("room", "room")])
def test_the_last_hop_sits_beside_the_application(application, expected):
    placement = place(figure1(), {"room": ROOM, "hmd": HMD}, DATA_HOSTS, {"rel/C/A": {application}})
    assert placement.hosts["concat"] == expected


def test_an_input_of_unknown_origin_costs_nothing_and_ties_go_by_name():
    specs = {"relay": spec("relay", "d/unknown/E")}
    assert place(specs, {"room": ROOM, "hmd": HMD}, {}, {}).hosts == {"relay": "hmd"}


def test_labels_a_template_requires_are_respected():
    hosts = {"room": ROOM, "gpu": HostInfo("gpu", frozenset({"gpu", "camera"}))}
    placement = place(figure1(), hosts, DATA_HOSTS, {}, required_labels={"pnp": {"gpu"}})
    assert placement.hosts["pnp"] == "gpu"
    missing = place(figure1(), {"room": ROOM}, DATA_HOSTS, {}, required_labels={"pnp": {"gpu"}})
    assert "pnp" not in missing.hosts
    assert missing.unplaced["pnp"] == "no live host manager has the labels gpu"
    assert missing.hosts["concat"] == "room"  # the rest is placed all the same


def test_no_host_or_every_host_full_is_reported():
    assert place(figure1(), {}, DATA_HOSTS, {}).unplaced == {
        "pnp": "no host manager is alive",
        "concat": "no host manager is alive",
    }
    full = place(figure1(), {"room": HostInfo("room", capacity=1)}, DATA_HOSTS, {})
    assert full.hosts == {"pnp": "room"}
    assert "capacity" in full.unplaced["concat"]


def test_load_breaks_ties_between_hosts_equally_near():
    specs = {f"relay{i}": spec(f"relay{i}", f"d/unknown/E{i}") for i in range(4)}
    hosts = {"a": HostInfo("a", capacity=4), "b": HostInfo("b", capacity=4)}
    placed = place(specs, hosts, {}, {}).hosts
    assert sorted(placed.values()) == ["a", "a", "b", "b"]
    busy = {"a": HostInfo("a", cpu_load=0.9), "b": HostInfo("b")}
    assert set(place(specs, busy, {}, {}).hosts.values()) == {"b"}


def test_load_never_outweighs_a_crossing():
    busy_hmd = {"room": ROOM, "hmd": HostInfo("hmd", cpu_load=5.0)}
    assert LOAD_WEIGHT < 1
    assert place(figure1(), busy_hmd, DATA_HOSTS, {}).hosts["pnp"] == "hmd"


def test_a_placed_component_stays_unless_a_move_saves_a_crossing():
    hosts = {"room": ROOM, "hmd": HMD}
    # Everything ran on the room host while the HMD's host manager was away.
    current = {"pnp": "room", "concat": "room"}
    moved = place(figure1(), hosts, DATA_HOSTS, {}, current)
    assert moved.hosts["pnp"] == "hmd"  # saves the feature stream (1) for two statics (0.2)
    # concat then reads pnp across (1) or ART across (1): no saving, it stays.
    assert moved.hosts["concat"] == "room"
    # A cheaper host by less than the margin (load) does not move anything.
    assert LOAD_WEIGHT < MOVE_MARGIN
    busy_room = {"room": HostInfo("room", cpu_load=1.0), "hmd": HMD}
    specs = {"relay": spec("relay", "d/unknown/E")}
    assert place(specs, busy_room, {}, {}, {"relay": "room"}).hosts == {"relay": "room"}
    assert place(specs, busy_room, {}, {}).hosts == {"relay": "hmd"}
    # Nor does a static input together with load (a host that just joined looks idle).
    inversion = {"inv": spec("inv", MARKERS, static=(MARKERS,))}
    busy_hmd = {"room": ROOM, "hmd": HostInfo("hmd", cpu_load=1.0)}
    assert place(inversion, busy_hmd, DATA_HOSTS, {}, {"inv": "hmd"}).hosts == {"inv": "hmd"}


def test_a_vanished_host_leaves_its_components_to_be_placed_again():
    current = {"pnp": "hmd", "concat": "hmd"}
    placement = place(figure1(), {"room": ROOM}, DATA_HOSTS, {"rel/C/A": {"hmd"}}, current)
    assert placement.hosts == {"pnp": "room", "concat": "room"}


def test_placement_is_deterministic_whatever_the_order_of_hosts():
    forward = {"room": ROOM, "hmd": HMD}
    backward = {"hmd": HMD, "room": ROOM}
    assert (
        place(figure1(), forward, DATA_HOSTS, {}).hosts
        == place(figure1(), backward, DATA_HOSTS, {}).hosts
    )


def test_a_chain_moves_together_when_that_saves_a_crossing():
    """The fusion and the last hop ran beside the A.R.T. while the HMD's host manager was
    away: moving either alone saves nothing, moving both saves the camera's crossing."""
    specs = {
        "pnp": spec("pnp", CAMERA_INTRINSICS, CAMERA_FEATURES, MARKERS, static=STATICS),
        "art": spec("art", ART_HT),
        "fusion": spec("fusion", "d/pnp/out", "d/art/out"),
        "last": spec("last", "d/fusion/out", "d/store/WT_A", relations=("rel/C/A",)),
    }
    hosts = {"room": ROOM, "hmd": HMD}
    readers = {"rel/C/A": {"hmd"}}
    current = {"pnp": "hmd", "art": "room", "fusion": "room", "last": "room"}
    moved = place(specs, hosts, DATA_HOSTS, readers, current).hosts
    assert moved == {"pnp": "hmd", "art": "room", "fusion": "hmd", "last": "hmd"}
    # Placed so from the start, it stays so (no flapping back and forth).
    assert place(specs, hosts, DATA_HOSTS, readers, moved).hosts == moved


def test_a_fusion_goes_where_its_application_is_whatever_the_hosts_load():
    """The fusion reads the camera's chain on the HMD and the A.R.T. chain in the room: one
    crossing either way, but the last hop, beside the application on the HMD, can follow it
    there only: the HMD wins even when the room's host manager reads a lower load (one machine
    in two network namespaces, each reading it at another moment)."""
    specs = {
        "pnp": spec("pnp", CAMERA_INTRINSICS, CAMERA_FEATURES, MARKERS, static=STATICS),
        "art": spec("art", ART_HT),
        "fusion": spec("fusion", "d/pnp/out", "d/art/out"),
        "last": spec("last", "d/fusion/out", "d/store/WT_A", relations=("rel/C/A",)),
    }
    for hmd_load, room_load in ((0.8, 0.0), (0.0, 0.8), (1.0, 1.0), (1.0, 0.98)):
        hosts = {
            "room": HostInfo("room", cpu_load=room_load),
            "hmd": HostInfo("hmd", cpu_load=hmd_load),
        }
        placed = place(specs, hosts, DATA_HOSTS, {"rel/C/A": {"hmd"}}).hosts
        assert placed == {"pnp": "hmd", "art": "room", "fusion": "hmd", "last": "hmd"}
    assert DOWNSTREAM_WEIGHT + LOAD_WEIGHT < 1  # near the data still always wins
    # Read by an application in the room, the same derivation ends there.
    placed = place(specs, {"room": ROOM, "hmd": HMD}, DATA_HOSTS, {"rel/C/A": {"room"}}).hosts
    assert placed == {"pnp": "hmd", "art": "room", "fusion": "room", "last": "room"}


# -- containers: a host's components grouped (issue 28) ----------------------------------------


def chain(prefix, length, source="d/art/ART_HT"):
    """``length`` components in a chain reading ``source``: one derivation."""
    specs, key = {}, source
    for i in range(length):
        specs[f"{prefix}{i}"] = spec(f"{prefix}{i}", key)
        key = f"d/{prefix}{i}/out"
    return specs


def members(groups):
    return {name: [s.instance for s in group.components] for name, group in groups.items()}


def test_a_derivation_stays_in_one_container_and_derivations_share_the_cores():
    specs = {**chain("a", 3), **chain("b", 2), **chain("c", 1)}
    hosts = dict.fromkeys(specs, "room")
    groups = group_containers(specs, hosts, {"room": 2})
    assert members(groups) == {"room-0": ["a0", "a1", "a2"], "room-1": ["b0", "b1", "c0"]}
    assert [len(g.wires) for g in groups.values()] == [2, 1]
    assert group_containers(specs, hosts, {"room": 1}).keys() == {"room-0"}


def test_containers_are_per_host_and_isolation_gives_a_container_of_its_own():
    specs = {**chain("a", 2), **chain("b", 2)}
    hosts = {"a0": "room", "a1": "hmd", "b0": "hmd", "b1": "hmd"}
    groups = group_containers(specs, hosts, {"room": 4, "hmd": 4}, isolated={"b1"})
    assert members(groups) == {
        "hmd-b1": ["b1"],
        "hmd-0": ["a1"],  # its producer is on the room's host: a derivation of its own here
        "hmd-1": ["b0"],
        "room-0": ["a0"],
    }
    alone = group_containers(specs, hosts, {"hmd": 1}, isolating_hosts={"hmd"})
    assert sorted(alone) == ["hmd-a1", "hmd-b0", "hmd-b1", "room-0"]


def test_a_derivation_already_running_stays_in_its_container():
    specs = {**chain("a", 1), **chain("b", 1)}
    hosts = dict.fromkeys(specs, "room")
    fresh = group_containers(specs, hosts, {"room": 2})
    assert members(fresh) == {"room-0": ["a0"], "room-1": ["b0"]}
    specs = {**chain("c", 3), **specs}  # a larger derivation joins: the others do not move
    kept = group_containers(
        specs, dict.fromkeys(specs, "room"), {"room": 2}, current={"a0": "room-0", "b0": "room-1"}
    )
    assert members(kept) == {"room-0": ["c0", "c1", "c2", "a0"], "room-1": ["b0"]}
    unplaced = group_containers(specs, {"a0": "room"}, {"room": 2})
    assert members(unplaced) == {"room-0": ["a0"]}


def test_running_components_never_move_and_new_ones_join_most_of_their_derivation():
    specs = chain("a", 4)  # a0 -> a1 -> a2 -> a3, one derivation
    hosts = dict.fromkeys(specs, "room")
    # a0 and a1 run in room-1, a3 in room-0 (joined into one derivation by a2, new)
    current = {"a0": "room-1", "a1": "room-1", "a3": "room-0"}
    groups = group_containers(specs, hosts, {"room": 2}, current=current)
    assert members(groups) == {"room-0": ["a3"], "room-1": ["a0", "a1", "a2"]}
    # a container beyond the host's cores (it has fewer now) is not kept: grouped afresh
    fewer = group_containers(specs, hosts, {"room": 1}, current=current)
    assert members(fewer) == {"room-0": ["a0", "a1", "a2", "a3"]}
