"""The NatNet adapter without a network: packets in, measurements and counters out."""

from __future__ import annotations

import dataclasses
import logging
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from tests.unit.natnet_sdk_layout import (
    sdk_connect_request,
    sdk_frame,
    sdk_model_definitions,
    sdk_server_info,
)
from ubitrack_agent.core import ErrorPose
from ubitrack_agent.io.natnet import format as natnet
from ubitrack_agent.io.natnet.adapter import NatNetAdapter
from ubitrack_agent.io.natnet.format import NatNetVersion
from ubitrack_agent.sim_trackers.scenario import load_scenario
from ubitrack_agent.sim_trackers.sim_natnet import NatNetServer, NatNetSimulator, body_names

SCENARIO = load_scenario()
T0 = 1_763_700_000_000_000_000
HEAD = (1, (0.5, 1.25, -0.75, 0.0, 0.0, 0.38268343, 0.92387953), 0.0004, True)
TABLE = (5, (-1.5, 0.25, 2.0, 0.5, 0.5, 0.5, 0.5), 0.0011, True)


class Recorder:
    def __init__(self) -> None:
        self.published: list[tuple[str, object]] = []

    def publish(self, edge_name, measurement) -> None:
        self.published.append((edge_name, measurement))


def _adapter(**options) -> tuple[NatNetAdapter, Recorder]:
    options.setdefault("bodies", {"Head": "HT"})
    options.setdefault("body_ids", {5: "TB"})
    return NatNetAdapter("OT", static_bodies=("TB",), **options), Recorder()


@pytest.mark.parametrize("version", [(3, 1), (4, 2)], ids=str)
def test_negotiation_naming_and_publishing(version):
    adapter, recorder = _adapter()
    assert {(e.name, e.static) for e in adapter.edges} == {("OT_HT", False), ("OT_TB", True)}
    frame = sdk_frame(version, 1, [HEAD, TABLE])
    assert adapter.handle(frame, T0, recorder) == 0  # no version yet
    assert adapter.counters["before_server_info"] == 1
    adapter.handle(sdk_server_info((*version, 0, 0)), T0, recorder)
    assert adapter.version == (*version, 0, 0)
    # Before the model definitions only the body mapped by id is known.
    assert adapter.handle(frame, T0, recorder) == 1 and adapter.wants_models
    assert recorder.published[-1][0] == "OT_TB"
    assert adapter.counters["before_model_definitions"] == 1
    adapter.handle(sdk_model_definitions(version, {1: "Head", 5: "Table"}), T0, recorder)
    assert adapter.names == {1: "Head", 5: "Table"} and not adapter.wants_models
    assert adapter.handle(frame, T0 + 1, recorder) == 2
    adapter.handle(sdk_model_definitions(version, {1: "Head", 5: "Table", 9: "Cup"}), T0, recorder)
    adapter.handle(sdk_frame(version, 2, [(9, *HEAD[1:])]), T0, recorder)
    assert adapter.counters["unmapped_body_9"] == 1 and not adapter.wants_models
    (head_edge, head), (table_edge, _) = recorder.published[-2:]
    assert (head_edge, table_edge) == ("OT_HT", "OT_TB")
    assert isinstance(head, ErrorPose) and head.timestamp_ns == T0 + 1
    np.testing.assert_allclose(head.translation, (0.5, 1.25, -0.75), atol=1e-6)
    np.testing.assert_allclose(abs(np.dot(head.rotation, HEAD[1][3:])), 1.0, atol=1e-6)
    assert adapter.counters["rejected"] == 0


def test_untracked_bodies_and_large_marker_errors_are_left_out():
    adapter, recorder = _adapter(max_marker_error_mm=1.0)
    adapter.handle(sdk_server_info((4, 1, 0, 0)), T0, recorder)
    adapter.handle(sdk_model_definitions((4, 1), {1: "Head", 5: "Table"}), T0, recorder)
    lost_head = (1, HEAD[1], 0.0004, False)
    assert adapter.handle(sdk_frame((4, 1), 2, [lost_head, TABLE]), T0, recorder) == 0
    assert adapter.counters["untracked_OT_HT"] == 1
    assert adapter.counters["marker_error_OT_TB"] == 1  # 1.1 mm > 1.0 mm
    assert adapter.handle(sdk_frame((4, 1), 3, [HEAD]), T0, recorder) == 1


def test_device_timestamps_subtract_natnet_latency():
    adapter, recorder = _adapter(timestamps="device")
    adapter.handle(sdk_server_info((3, 1, 0, 0), frequency=10_000_000), T0, recorder)
    # 10 MHz ticks: transmit - exposure = 25_000 ticks = 2.5 ms
    adapter.handle(sdk_frame((3, 1), 1, [TABLE], stamps=(100_000, 110_000, 125_000)), T0, recorder)
    assert recorder.published[-1][1].timestamp_ns == T0 - 2_500_000
    adapter.handle(sdk_frame((3, 1), 2, [TABLE], stamps=(0, 0, 0)), T0, recorder)
    assert recorder.published[-1][1].timestamp_ns == T0
    assert adapter.counters["latency_unusable"] == 1


def test_a_models_changed_frame_asks_for_the_definitions_again():
    adapter, recorder = _adapter()
    adapter.handle(sdk_server_info((4, 0, 0, 0)), T0, recorder)
    adapter.handle(sdk_model_definitions((4, 0), {1: "Head"}), T0, recorder)
    assert not adapter.wants_models
    adapter.handle(sdk_frame((4, 0), 1, [HEAD], params=0x02), T0, recorder)
    assert adapter.wants_models


def test_an_unsupported_server_version_parses_nothing():
    adapter, recorder = _adapter()
    payload = b"Motive".ljust(256, b"\0") + bytes([1, 10, 0, 0, 2, 10, 0, 0])
    adapter.handle(struct.pack("<HH", 1, len(payload)) + payload, T0, recorder)
    assert adapter.handle(sdk_frame((3, 1), 1, [TABLE]), T0, recorder) == 0
    assert adapter.counters["unsupported_version"] == 1


def test_hostile_packets_are_typed_counted_and_logged_rate_limited(caplog):
    adapter, recorder = _adapter()
    adapter.handle(sdk_server_info((4, 1, 0, 0)), T0, recorder)
    good = sdk_frame((4, 1), 1, [TABLE])
    with caplog.at_level(logging.WARNING, logger="ubitrack.adapter"):
        for i in range(50):
            assert adapter.handle(good[: 20 + i], T0, recorder) == 0  # header size disagrees
        bad_body = bytearray(good)
        struct.pack_into("<i", bad_body, 4 + 4, -1)  # a negative marker-set count
        assert adapter.handle(bytes(bad_body), T0, recorder) == 0
    assert adapter.counters["rejected"] == 51
    assert adapter.counters["rejected_packet"] == 50 and adapter.counters["rejected_frame"] == 1
    rejections = [r for r in caplog.records if "rejected input" in r.getMessage()]
    assert len(rejections) == 10  # the first ten, then every thousandth


@settings(max_examples=200, deadline=None)
@given(st.binary(min_size=0, max_size=400), st.sampled_from([1, 5, 7, 3, 8, 100, 9999]))
def test_any_packet_is_handled_without_raising(body, message_id):
    adapter, recorder = _adapter()
    adapter.handle(sdk_server_info((4, 1, 0, 0)), T0, recorder)
    packet = struct.pack("<HH", message_id, len(body)) + body
    adapter.handle(packet, T0, recorder)
    assert adapter.counters["received"] == 2


def test_the_simulated_optitrack_through_the_adapter_matches_ground_truth():
    art = dataclasses.replace(SCENARIO.art, dropout=0.0)
    simulator = NatNetSimulator(SCENARIO.world, art, np.random.default_rng(11), latency_ms=3.0)
    adapter = NatNetAdapter(
        art.frame, body_names(art), static_bodies=art.static_bodies, timestamps="device"
    )
    recorder = Recorder()
    with NatNetServer(simulator, "127.0.0.1", 0, 0, NatNetVersion(4, 1)) as server:
        sender = ("127.0.0.1", 40002)
        adapter.handle(server.answer(sdk_connect_request((4, 1, 0, 0)), sender), T0, recorder)
        models = server.answer(natnet.build_request(natnet.NAT_REQUEST_MODELDEF), sender)
        adapter.handle(models, T0, recorder)
    errors_mm, errors_deg = [], []
    for i in range(200):
        sent = T0 + i * 16_666_667
        exposure = simulator.frame(sent - 3_000_000, 10**12 + i * 16_666_667)
        frame = natnet.build_frame(exposure, server.version)
        adapter.handle(frame, sent, recorder)  # received the instant it was sent
        for name, pose in recorder.published[-2:]:
            assert pose.timestamp_ns == sent - 3_000_000  # the exposure time
            q, t = SCENARIO.world.pose("ART", name.split("_")[1], pose.timestamp_ns)
            errors_mm.append(1000 * (pose.translation - t))
            delta = Rotation.from_quat(pose.rotation) * Rotation.from_quat(q).inv()
            errors_deg.append(np.degrees(delta.as_rotvec()))
    assert len(recorder.published) == 400
    # the scenario's noise: 0.3 mm and 0.05 deg per axis (in place: position error grows
    # with the body's distance only through the rotation noise, small here)
    assert np.std(errors_mm) == pytest.approx(0.3, rel=0.25)
    assert np.std(errors_deg) == pytest.approx(0.05, rel=0.25)
    assert abs(np.mean(errors_mm)) < 0.05


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=400))
def test_the_simulated_server_answers_any_datagram_without_raising(datagram):
    simulator = NatNetSimulator(SCENARIO.world, SCENARIO.art, np.random.default_rng(0))
    with NatNetServer(simulator, "127.0.0.1", 0, 0, NatNetVersion(4, 1)) as server:
        reply = server.answer(datagram, ("127.0.0.1", 40003))
        if len(datagram) < 4:
            assert reply is None and server.counters["rejected"] == 1
        elif reply is not None:
            natnet.split_packet(reply)  # a well-formed packet


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.floats(width=32, allow_nan=False, allow_infinity=False), min_size=8, max_size=8),
    st.booleans(),
)
def test_any_finite_rigid_body_is_published_or_rejected(values, valid):
    """Huge positions, zero or tiny quaternions, negative errors: never an exception."""
    adapter, recorder = _adapter()
    adapter.handle(sdk_server_info((4, 1, 0, 0)), T0, recorder)
    pose, error = tuple(values[:7]), values[7]
    published = adapter.handle(sdk_frame((4, 1), 1, [(5, pose, error, valid)]), T0, recorder)
    assert published + adapter.counters["rejected"] + adapter.counters["untracked_OT_TB"] == 1
