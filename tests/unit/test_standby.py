"""Which retired components stay on standby (``ubitrack_agent.agent.standby``): the old
derivation of a relation that read an edge the live SRG lost, whole, and nothing else."""

from __future__ import annotations

from ubitrack_agent.agent.standby import standby_components
from ubitrack_agent.net.spec import ComponentSpec, InputBinding

ART_HT, CAMERA = "d/data/ART/ART_HT", "d/data/camera/pose"
C_A = "d/relation/C/A/6D"


def spec(instance: str, reads: list[str], relation: bool = False) -> ComponentSpec:
    """A component reading ``reads`` (a worker's output when it names one: ``d/data/<x>/out``
    of component ``x``), writing ``d/data/<instance>/out``."""
    inputs = tuple(
        InputBinding(f"in{k}", key, trigger=True, from_worker=key.endswith("/out"))
        for k, key in enumerate(reads)
    )
    return ComponentSpec(
        instance,
        "concatenation",
        inputs,
        {"out": f"d/data/{instance}/out"},
        relations={"out": (C_A,)} if relation else {},
    )


def out(instance: str) -> str:
    return f"d/data/{instance}/out"


# figure 1's fused flow: the tracker's way and the camera's way into one fusion, then C->A
FUSED = {
    "art-way": spec("art-way", [ART_HT]),
    "camera-way": spec("camera-way", [CAMERA]),
    "fusion": spec("fusion", [out("art-way"), out("camera-way")]),
    "c-a": spec("c-a", [out("fusion")], relation=True),
}


def test_the_old_derivation_of_a_relation_that_lost_an_edge_is_kept_whole():
    retired = set(FUSED)  # the camera-only flow replaces all of it
    assert standby_components(FUSED, retired, live_keys={CAMERA}) == retired


def test_only_retired_components_are_kept_the_shared_ones_run_on_anyway():
    retired = {"art-way", "fusion", "c-a"}  # camera-way serves the new flow too
    assert standby_components(FUSED, retired, live_keys={CAMERA}) == retired


def test_a_derivation_replaced_while_every_edge_it_reads_is_live_is_stopped():
    """A better tracker joins: the old flow lost nothing and is not worth keeping."""
    assert standby_components(FUSED, set(FUSED), live_keys={CAMERA, ART_HT}) == set()


def test_components_that_are_no_relations_derivation_are_stopped():
    running = {**FUSED, "spare": spec("spare", [ART_HT])}
    assert standby_components(running, {"spare"}, live_keys={CAMERA}) == set()


def test_a_derivation_is_followed_through_every_level_upstream():
    chain = {f"step{k}": spec(f"step{k}", [out(f"step{k - 1}")]) for k in range(1, 6)}
    running = {
        "step0": spec("step0", [ART_HT]),
        **chain,
        "last": spec("last", [out("step5")], relation=True),
    }
    assert standby_components(running, set(running), live_keys=set()) == set(running)
