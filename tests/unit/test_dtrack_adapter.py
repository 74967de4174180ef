"""The DTrack adapter on hand-written datagrams: hybrid bodies, measurement tools and
Flysticks as 6D edges, ts2, untracked items and skipped line types warned about once."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from ubitrack_agent.core import ErrorPose
from ubitrack_agent.io.dtrack.adapter import DTrackAdapter

T0 = 1_763_700_000_123_456_000
IDENTITY = "[1 0 0 0 1 0 0 0 1]"
ZERO_MATRIX = "[0 0 0 0 0 0 0 0 0]"


class Recorder:
    def __init__(self) -> None:
        self.published: list[tuple[str, ErrorPose]] = []
        self.left_out: list[str] = []

    def publish(self, edge_name, measurement) -> None:
        self.published.append((edge_name, measurement))

    def missed(self, edge_name) -> None:
        self.left_out.append(edge_name)


def _adapter(timestamps="receive") -> DTrackAdapter:
    return DTrackAdapter(
        "ART",
        {0: "WT", 1: "HT"},
        static_bodies=("WT",),
        tools={0: "P"},
        flysticks={0: "FS"},
        sigma_mm=0.5,
        sigma_deg=0.1,
        timestamps=timestamps,
    )


def _handle(adapter: DTrackAdapter, text: str, received_ns: int = T0) -> Recorder:
    recorder = Recorder()
    adapter.handle(text.encode(), received_ns, recorder)
    return recorder


def test_tools_and_flysticks_are_6d_edges():
    assert [(e.name, e.type, e.static) for e in _adapter().edges] == [
        ("ART_WT", "6D", True),
        ("ART_HT", "6D", False),
        ("ART_P", "6D", False),
        ("ART_FS", "6D", False),
    ]


def test_an_untracked_body_does_not_stop_the_others():
    recorder = _handle(
        _adapter(), f"fr 1\n6d 2 [0 1.000][0 0 0 0 0 0]{ZERO_MATRIX}[1 1.000][1000 0 0]{IDENTITY}"
    )
    assert [name for name, _ in recorder.published] == ["ART_HT"]
    np.testing.assert_array_equal(recorder.published[0][1].translation, [1, 0, 0])
    # a whole frame: the dynamic edges it left out missed their sample (static WT is kept)
    assert sorted(recorder.left_out) == ["ART_FS", "ART_P"]


def test_a_body_left_out_of_a_frame_missed_its_sample_and_a_rejected_datagram_says_nothing():
    recorder = _handle(_adapter(), f"fr 1\n6d 1 [0 1.000][0 0 0 0 0 0]{IDENTITY}")
    assert [name for name, _ in recorder.published] == ["ART_WT"]
    assert sorted(recorder.left_out) == ["ART_FS", "ART_HT", "ART_P"]
    assert _handle(_adapter(), "fr 1\n6d x").left_out == []


def test_hybrid_bodies_use_the_body_mapping_and_replace_the_optical_pose():
    adapter = _adapter()
    recorder = _handle(
        adapter,
        f"fr 1\n6d 1 [1 1.000][1000 0 0 0 0 0]{IDENTITY}\n"
        f"6di 2 [1 3 0.1][2000 0 0]{IDENTITY}[0 0 0.0][0 0 0]{ZERO_MATRIX}\n",
    )
    assert [name for name, _ in recorder.published] == ["ART_HT"]
    np.testing.assert_array_equal(recorder.published[0][1].translation, [2, 0, 0])
    assert adapter.counters["published"] == 1


def test_flysticks_old_and_new_publish_their_pose_only():
    adapter = _adapter()
    for line in (
        f"6df 2 [0 1.000 32][0 1000 0 0 0 0]{IDENTITY}[1 1.000 0][0 0 0 0 0 0]{IDENTITY}",
        f"6df2 1 1 [0 1.000 6 2][0 1000 0]{IDENTITY}[5 0.5 -1.0]",
    ):
        recorder = _handle(adapter, f"fr 1\n{line}\n")
        ((name, pose),) = recorder.published
        assert name == "ART_FS" and isinstance(pose, ErrorPose)
        np.testing.assert_array_equal(pose.translation, [0, 1, 0])
    assert adapter.counters["unmapped_flystick_1"] == 1


def test_6dmt2_covariance_replaces_the_configured_position_noise():
    adapter = _adapter()
    covariance = "[0.04 0.01 0 0.09 0 0.16]"
    recorder = _handle(adapter, f"fr 1\n6dmt2 1 1 [0 1.000 1 1.5][0 0 0]{IDENTITY}[1]{covariance}")
    ((name, pose),) = recorder.published
    # At the origin the left-perturbation covariance is the in-place one: rotation from
    # --sigma-deg, position DTrack's (mm^2 to m^2).
    assert name == "ART_P"
    np.testing.assert_allclose(
        pose.covariance[3:, 3:], [[0.04, 0.01, 0], [0.01, 0.09, 0], [0, 0, 0.16]] * np.array(1e-6)
    )
    np.testing.assert_allclose(np.diag(pose.covariance[:3, :3]), [np.radians(0.1) ** 2] * 3)
    # A zero covariance (none computed) leaves the configured 0.5 mm; 6dmt has none.
    for line in (
        f"6dmt2 1 1 [0 1.000 0 1.5][0 0 0]{IDENTITY}[][0 0 0 0 0 0]",
        f"6dmt 1 [0 1.000 0][0 0 0]{IDENTITY}",
    ):
        pose = _handle(adapter, f"fr 1\n{line}").published[0][1]
        np.testing.assert_allclose(np.diag(pose.covariance[3:, 3:]), [0.0005**2] * 3)


def test_ts2_is_used_when_the_clocks_agree_else_receive_time_minus_latency(caplog):
    caplog.set_level(logging.WARNING, logger="ubitrack.adapter")
    adapter = _adapter("device")
    body = f"6d 1 [1 1.000][0 0 0 0 0 0]{IDENTITY}"
    sample = T0 - 5_000_000
    ts2 = f"ts2 {sample // 10**9} {sample % 10**9 // 1000} 3000"
    # ts2 wins over ts (here a wrong one) and has no midnight ambiguity.
    recorder = _handle(adapter, f"fr 1\nts 1.0\n{ts2}\n{body}")
    assert recorder.published[0][1].timestamp_ns == sample
    late = T0 + 200_000_000  # the controller's clock is 0.2 s behind
    for _ in range(2):
        recorder = _handle(adapter, f"fr 2\n{ts2}\n{body}", received_ns=late)
        assert recorder.published[0][1].timestamp_ns == late - 3_000_000
    assert adapter.counters["ts2_clock_off"] == 2
    assert caplog.text.count("more than 0.1 s off") == 1
    # With the receive policy, ts2 is not looked at.
    receive = _adapter("receive")
    recorder = _handle(receive, f"fr 1\n{ts2}\n{body}", received_ns=late)
    assert recorder.published[0][1].timestamp_ns == late and not receive.counters["ts2_clock_off"]


def test_unsupported_and_unknown_line_types_are_warned_once_and_counted(caplog):
    caplog.set_level(logging.WARNING, logger="ubitrack.adapter")
    adapter = _adapter()
    for frame in range(3):
        datagram = f"fr {frame}\ngl 0\nglcal 0\n6dj 0 0\n6dmtr 0 0\nst 1\n6dcov 0\nfuture 1\n"
        assert _handle(adapter, datagram).published == []
    for line_type in ("gl", "glcal", "6dj", "6dmtr", "st", "6dcov", "future"):
        assert adapter.counters[f"line_{line_type}"] == 3
        assert caplog.text.count(f"line type {line_type!r}") == 1
    assert "unsupported line type '6dcov'" in caplog.text
    assert "unknown line type 'future'" in caplog.text
    assert adapter.counters["rejected"] == 0


def test_line_types_beyond_the_bound_share_one_counter():
    adapter = _adapter()
    _handle(adapter, "fr 1\n" + "\n".join(f"x{i} 0" for i in range(40)))
    assert sum(name.startswith("line_x") for name in adapter.counters) == 32
    assert adapter.counters["line_other"] == 8


@pytest.mark.parametrize(
    ("datagram", "message"),
    [
        (
            "fr 1\nts2 0 0 9999999999999999\n6d 1 [1 1.000][0 0 0]" + IDENTITY,
            "datagram out of range",
        ),
        ("fr 1\n6d 1 [0 1.000][1 2][1 0 0 0 1 0 0 0 1]", "6d body 0 position: expected 3"),
        ("fr 1\n6df2 1 1 [0 1.000 6][0 0 0]" + IDENTITY + "[]", "6df2 Flystick 0: expected 4"),
        ("fr 1\n6d 1 [0 1.000][1e305 0 0]" + IDENTITY, "datagram out of range"),
    ],
)
@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")  # the 1e305 mm case
def test_a_malformed_known_line_rejects_the_datagram_naming_where(caplog, datagram, message):
    adapter = _adapter("device")
    assert _handle(adapter, datagram).published == []
    assert adapter.counters["rejected"] == 1 and message in caplog.text
