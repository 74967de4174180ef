"""The switch benchmark's arithmetic (``bench/switch_bench.py``): what it counts from the samples
it recorded, on samples made by hand against a world at rest."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from bench.switch_bench import Wire, summarise
from ubitrack_agent.core import encode
from ubitrack_agent.core.measurements import ErrorPose

MS = 1_000_000
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])
SIGMA_M = 1e-3
"""Each sample's claimed error: 1 mm and 1 mrad, every axis."""


class AtRest:
    """A world where ``A`` stays at ``C``'s origin."""

    def pose(self, source: str, target: str, at_ns: int) -> tuple[np.ndarray, np.ndarray]:
        return IDENTITY, np.zeros(3)


def sample(stamp_ns: int, off_m: float) -> SimpleNamespace:
    pose = ErrorPose(stamp_ns, IDENTITY, np.array([off_m, 0.0, 0.0]), np.eye(6) * SIGMA_M**2)
    return SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: encode(pose)), attachment=None)


def recorded(stream: list[tuple[int, int, float]]) -> Wire:
    """A wire that took ``(arrival ms, stamp ms, error m)`` samples in that order."""
    wire = Wire()
    for arrived, stamp, off in stream:
        wire.take(sample(stamp * MS, off))
        wire.samples[-1] = (arrived * MS, *wire.samples[-1][1:])
    return wire


def test_a_switch_is_judged_by_the_samples_stamped_in_the_second_after_it() -> None:
    start = 10_000
    stream = [(start - 100 + 10 * k, start - 100 + 10 * k, 0.0002) for k in range(10)]
    stream += [
        (start + 300, start + 290, 0.02),  # 20 sigma off: NEES 400
        (start + 310, start + 290, 0.0002),  # the same instant again
        (start + 320, start + 250, 0.0002),  # older than one passed on
        (start + 330, start + 330, 0.0005),
    ]
    stream += [(start + 2_000 + 10 * k, start + 2_000 + 10 * k, 0.0003) for k in range(5)]
    stream += [(start + 2_050, start + 2_050, 0.01)]  # the steady state's outlier
    events = [{"kind": "A.R.T. off", "at_ns": start * MS, "from": "fused", "to": "camera only"}]
    world = SimpleNamespace(
        world=AtRest(), art=SimpleNamespace(rate=60.0), camera=SimpleNamespace(rate=30.0)
    )
    result = summarise(events, recorded(stream), world, {})
    (event,) = result["events"]
    assert event["samples"] == 2  # the 20 mm one and the last: the two others are not passed on
    assert event["beyond_3_sigma"] == 1
    assert event["beyond_3_sigma_samples"] == [[290.0, 20.0, 0.0, pytest.approx(400.0)]]
    assert event["error_mm_max"] == pytest.approx(20.0)
    assert (event["duplicates"], event["out_of_order"]) == (1, 2)
    assert event["gap_ms"] == pytest.approx(310.0)  # the last sample before to the first after
    assert event["gap_frames"] == pytest.approx(310.0 / 1e3 * 60.0)
    steady = result["steady"]["camera only"]
    assert steady["samples"] == 6 and steady["error_mm_max"] == pytest.approx(10.0)
    assert steady["nees_mean"] == pytest.approx((5 * 0.09 + 100.0) / 6)
    assert event["steady_beyond_3_sigma_samples"] == [[2050.0, 10.0, 0.0, pytest.approx(100.0)]]
    kind = result["kinds"]["A.R.T. off"]
    assert kind["events_worse_than_steady_p99"] == 1  # 20 mm against the steady state's p99
    assert kind["nees_mean"] == pytest.approx((400.0 + 0.25) / 2)


def test_the_mean_nees_is_judged_over_events_and_steady_stretches() -> None:
    """Each event's second is one batch of its kind, each stretch between events one of its
    flow's steady state (``bench.synthetic.nees_over_batches``); one batch has no interval."""
    first, second = 10_000, 14_000
    stream = [(first + 10 * k, first + 10 * k, 0.001) for k in range(10)]  # NEES 1 each
    stream += [(first + 2_000 + 10 * k, first + 2_000 + 10 * k, 0.002) for k in range(10)]
    stream += [(second + 10 * k, second + 10 * k, 0.002) for k in range(10)]  # NEES 4
    stream += [(second + 2_000 + 10 * k, second + 2_000 + 10 * k, 0.003) for k in range(10)]
    events = [
        {"kind": "camera off", "at_ns": at * MS, "from": "fused", "to": "A.R.T. only"}
        for at in (first, second)
    ]
    world = SimpleNamespace(
        world=AtRest(), art=SimpleNamespace(rate=60.0), camera=SimpleNamespace(rate=30.0)
    )
    result = summarise(events, recorded(stream), world, {})
    over_events = result["kinds"]["camera off"]["nees_over_events"]
    assert over_events["batch_means"] == [pytest.approx(1.0), pytest.approx(4.0)]
    assert over_events["mean"] == pytest.approx(2.5)
    stretches = result["steady"]["A.R.T. only"]["nees_over_stretches"]
    assert stretches["batch_means"] == [pytest.approx(4.0), pytest.approx(9.0)]
    assert result["steady"]["fused"]["nees_over_stretches"] is None


def test_a_flows_own_gaps_are_measured_within_its_stretches() -> None:
    """Two stretches of the same flow (an event from fused to fused between them): the silence
    from the first's last arrival to the second's first, under the 1.5 s the second waits
    after its event when the first's last sample came late, is no gap of the flow."""
    first, second = 10_000, 11_600
    stream = [(first + 10 * k + 30, first + 10 * k, 0.001) for k in range(160)]
    stream += [(second + 1_500 + 5, second + 1_500, 0.001)]  # came fast: 1,475 ms after
    stream += [(second + 1_510 + 10 * k + 30, second + 1_510 + 10 * k, 0.001) for k in range(20)]
    events = [
        {"kind": "worker killed", "at_ns": at * MS, "from": "fused", "to": "fused"}
        for at in (first, second)
    ]
    world = SimpleNamespace(
        world=AtRest(), art=SimpleNamespace(rate=60.0), camera=SimpleNamespace(rate=30.0)
    )
    steady = summarise(events, recorded(stream), world, {})["steady"]["fused"]
    assert steady["gap_ms_max"] == pytest.approx(35.0)  # the fast one to the next
    assert steady["gap_ms_p99"] <= 35.0
