"""Which inputs get a clock offset (``agent/clocks.py``): components reading hosts whose clocks
differ by more than their tolerance are moved to the agent's clock, the others are left alone,
and what cannot be aligned is reported with the reason."""

from __future__ import annotations

from dataclasses import replace

import pytest

from ubitrack_agent.agent.clocks import correct_clocks
from ubitrack_agent.net.clock import ClockEstimate
from ubitrack_agent.net.config import MAX_CLOCK_OFFSET_NS
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.spec import ComponentSpec, InputBinding, parse_spec

KEYS = KeySpace("ubitrack/test")
MS = 10**6
ART, CAM, STORE = KEYS.data("ART/HT"), KEYS.data("cam/F1"), KEYS.data("store/C_HT")
DATA_HOSTS = {ART: "art-pc", CAM: "hmd", STORE: "agent-pc"}
ESTIMATES = {
    "art-pc": ClockEstimate(20_000, 50_000, 100_000, 8),
    "hmd": ClockEstimate(-300 * MS, 80_000, 160_000, 8),
    "agent-pc": ClockEstimate(1_000, 10_000, 20_000, 8),
}
PLACEMENT = {"fuse": "agent-pc", "pose": "hmd", "concat": "agent-pc", "after": "agent-pc"}


def spec(instance: str, *inputs: InputBinding, tolerance_ms: float = 5.0) -> ComponentSpec:
    return ComponentSpec(
        instance=instance,
        service="fusion",
        inputs=inputs,
        outputs={"out": KEYS.data(f"{instance}/out")},
        tolerance_ms=tolerance_ms,
    )


def dynamic(key: str, trigger: bool = True) -> InputBinding:
    return InputBinding("in", key, trigger=trigger)


def out(instance: str) -> str:
    return KEYS.data(f"{instance}/out")


FUSE = spec("fuse", dynamic(ART), dynamic(CAM))


def offsets(specs: dict[str, ComponentSpec], instance: str) -> list[int]:
    return [binding.clock_offset_ns for binding in specs[instance].inputs]


def test_fusing_hosts_300_ms_apart_moves_each_input_to_the_agents_clock():
    specs, reasons = correct_clocks({"fuse": FUSE}, DATA_HOSTS, PLACEMENT, ESTIMATES)
    assert offsets(specs, "fuse") == [20_000, -300 * MS]
    assert reasons == {}
    assert parse_spec(specs["fuse"].to_json()) == specs["fuse"]  # a valid specification


def test_clocks_within_the_tolerance_are_left_alone():
    close = {**ESTIMATES, "hmd": ClockEstimate(-4 * MS, 80_000, 160_000, 8)}
    specs, reasons = correct_clocks({"fuse": FUSE}, DATA_HOSTS, PLACEMENT, close)
    assert specs["fuse"] == FUSE and reasons == {}
    loose = {"fuse": replace(FUSE, tolerance_ms=400.0)}  # 300 ms apart, within 400 ms
    specs, reasons = correct_clocks(loose, DATA_HOSTS, PLACEMENT, ESTIMATES)
    assert specs == loose and reasons == {}


def test_one_host_alone_is_never_corrected():
    pose = spec("pose", dynamic(CAM), InputBinding("c", STORE, static=True))
    specs, reasons = correct_clocks({"pose": pose}, DATA_HOSTS, PLACEMENT, ESTIMATES)
    assert specs["pose"] == pose and reasons == {}


@pytest.mark.parametrize(
    "estimates, hosts, named",
    [
        ({**ESTIMATES, "hmd": None}, DATA_HOSTS, "host hmd"),  # not measured yet
        ({"art-pc": ESTIMATES["art-pc"]}, DATA_HOSTS, "host hmd"),  # no host manager there
        (ESTIMATES, {ART: "art-pc"}, "an unknown host"),  # the camera's host is not known
        (
            {**ESTIMATES, "hmd": ClockEstimate(MAX_CLOCK_OFFSET_NS + 1, 0, 0, 1)},
            DATA_HOSTS,
            "host hmd",
        ),
    ],
)
def test_a_clock_without_a_usable_estimate_is_reported_and_nothing_changes(estimates, hosts, named):
    specs, reasons = correct_clocks({"fuse": FUSE}, hosts, PLACEMENT, estimates)
    assert specs["fuse"] == FUSE
    assert f"no usable clock offset for {named}" in reasons["fuse"]


def test_estimates_too_uncertain_are_applied_and_reported():
    vague = {
        **ESTIMATES,
        "art-pc": ClockEstimate(0, 2 * MS, 4 * MS, 8),
        "hmd": ClockEstimate(-300 * MS, 4 * MS, 8 * MS, 8),
    }
    specs, reasons = correct_clocks({"fuse": FUSE}, DATA_HOSTS, PLACEMENT, vague)
    assert offsets(specs, "fuse") == [0, -300 * MS]
    assert "may still be 6.000 ms apart" in reasons["fuse"]
    assert "more than the tolerance of 5 ms" in reasons["fuse"]


def test_static_inputs_do_not_count():
    with_static = spec("fuse", dynamic(ART), InputBinding("c", CAM, static=True))
    specs, reasons = correct_clocks({"fuse": with_static}, DATA_HOSTS, PLACEMENT, ESTIMATES)
    assert specs["fuse"] == with_static and reasons == {}


CHAIN = {
    # the camera's pose, on the camera's clock: one host, left alone
    "pose": spec("pose", dynamic(CAM)),
    # fused with the tracker: corrected, so its output is on the agent's clock
    "fuse": spec("fuse", dynamic(ART), dynamic(out("pose"))),
    # the fused pose (agent's clock) with the tracker (20 us off): within the tolerance
    "after": spec("after", dynamic(out("fuse")), dynamic(ART, trigger=False)),
    # the fused pose with the camera's raw features: only the camera is moved
    "concat": spec("concat", dynamic(out("fuse")), dynamic(CAM, trigger=False)),
}


def test_a_components_output_is_on_its_inputs_clock_or_the_agents_once_corrected():
    specs, reasons = correct_clocks(CHAIN, DATA_HOSTS, PLACEMENT, ESTIMATES)
    assert offsets(specs, "pose") == [0]
    assert offsets(specs, "fuse") == [20_000, -300 * MS]
    assert offsets(specs, "after") == [0, 0]
    assert offsets(specs, "concat") == [0, -300 * MS]
    assert reasons == {}


def test_the_order_of_the_specifications_does_not_matter():
    backwards = dict(reversed(CHAIN.items()))
    assert (
        correct_clocks(backwards, DATA_HOSTS, PLACEMENT, ESTIMATES)[0]
        == (correct_clocks(CHAIN, DATA_HOSTS, PLACEMENT, ESTIMATES)[0])
    )
    assert list(correct_clocks(backwards, DATA_HOSTS, PLACEMENT, ESTIMATES)[0]) == list(backwards)


def test_an_uncorrectable_output_makes_its_consumers_clock_unknown_too():
    specs, reasons = correct_clocks(CHAIN, DATA_HOSTS, PLACEMENT, {**ESTIMATES, "hmd": None})
    assert set(reasons) == {"fuse", "after", "concat"}  # "pose" reads one host: no need
    assert "no usable clock offset for host hmd" in reasons["fuse"]
    assert "no usable clock offset for an unknown host" in reasons["after"]
    assert all(offsets(specs, i) == [0, 0] for i in ("fuse", "after", "concat"))


def test_a_loop_of_components_is_no_known_clock_and_ends():
    loop = {
        "a": spec("a", dynamic(out("b")), dynamic(ART)),
        "b": spec("b", dynamic(out("a")), dynamic(ART)),
    }
    specs, reasons = correct_clocks(loop, DATA_HOSTS, PLACEMENT, ESTIMATES)
    assert specs == loop and set(reasons) <= {"a", "b"}


def test_a_refreshed_estimate_within_its_uncertainty_keeps_the_offset_sent():
    first, _ = correct_clocks({"fuse": FUSE}, DATA_HOSTS, PLACEMENT, ESTIMATES)
    drifted = {**ESTIMATES, "hmd": ClockEstimate(-300 * MS + 60_000, 80_000, 160_000, 8)}
    kept, _ = correct_clocks({"fuse": FUSE}, DATA_HOSTS, PLACEMENT, drifted, previous=first)
    assert kept == first  # no rewire for a 60 us change within 80 us
    moved = {**ESTIMATES, "hmd": ClockEstimate(-299 * MS, 80_000, 160_000, 8)}
    new, _ = correct_clocks({"fuse": FUSE}, DATA_HOSTS, PLACEMENT, moved, previous=first)
    assert offsets(new, "fuse") == [20_000, -299 * MS]


def test_a_clock_far_ahead_of_the_host_running_the_component_is_reported():
    """The worker refuses samples stamped more than 10 s ahead of its own clock, before any
    correction: an input whose host's clock reads 20 s ahead of it is lost."""
    behind = {**ESTIMATES, "agent-pc": ClockEstimate(20_000 * MS, 10_000, 20_000, 8)}
    specs, reasons = correct_clocks({"fuse": FUSE}, DATA_HOSTS, PLACEMENT, behind)
    assert (
        "the clock of host art-pc reads 20.0 s ahead of that of host agent-pc" in (reasons["fuse"])
    )
    assert offsets(specs, "fuse") == [20_000, -300 * MS]  # corrected all the same
    assert "host hmd reads 20.3 s ahead" in reasons["fuse"]
    _, placed_elsewhere = correct_clocks({"fuse": FUSE}, DATA_HOSTS, {}, behind)
    assert placed_elsewhere == {}  # not placed: nothing to compare with
