"""The simulator's NatNet packets, parsed by code nobody here wrote: the PyPI client
``natnet`` (0.3; its own ``PacketBuffer``, ``ServerInfo``, ``DataDescriptions`` and
``DataFrame`` readers). It has no socket here: the simulator's server answers the requests
that client sends, and its frames are handed to the client's frame reader."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ubitrack_agent.io.natnet import format as ours
from ubitrack_agent.io.natnet.format import NatNetVersion
from ubitrack_agent.sim_trackers.scenario import load_scenario
from ubitrack_agent.sim_trackers.sim_natnet import NatNetServer, NatNetSimulator

natnet = pytest.importorskip("natnet", reason="the 'test' extra's natnet package is missing")
from natnet.data_descriptions import DataDescriptions  # noqa: E402
from natnet.data_frame import DataFrame  # noqa: E402
from natnet.packet_buffer import PacketBuffer  # noqa: E402
from natnet.server_info import ServerInfo  # noqa: E402
from natnet.version import Version  # noqa: E402

SCENARIO = load_scenario()
T0 = 1_763_700_000_000_000_000
VERSIONS = [NatNetVersion(3, 0), NatNetVersion(3, 1), NatNetVersion(4, 0), NatNetVersion(4, 1)]
VERSIONS += [NatNetVersion(4, 2)]


def _their_request(message_id: int, text: str = "") -> bytes:
    """What ``natnet.NatNetClient.send_request`` sends (its connect is ``Ping``)."""
    text = "Ping" if message_id == 0 else text
    payload = text.encode() + b"\0"
    return message_id.to_bytes(2, "little") + len(payload).to_bytes(2, "little") + payload


def _read(packet: bytes) -> tuple[int, PacketBuffer]:
    buffer = PacketBuffer(packet)
    message_id = buffer.read_uint16()
    assert buffer.read_uint16() == len(packet) - 4
    return message_id, buffer


@pytest.fixture
def server(request):
    art = dataclasses.replace(SCENARIO.art, dropout=0.0)
    simulator = NatNetSimulator(SCENARIO.world, art, np.random.default_rng(3))
    with NatNetServer(simulator, "127.0.0.1", 0, 0, request.param) as server:
        yield server


@pytest.mark.parametrize("server", VERSIONS, indirect=True, ids=str)
def test_their_client_reads_our_server_info_model_definitions_and_frames(server):
    sender = ("127.0.0.1", 40000)
    message_id, buffer = _read(server.answer(_their_request(0), sender))
    assert message_id == 1
    info = ServerInfo.read_from_buffer(buffer, None)
    assert info.application_name == "Motive"
    version = info.nat_net_protocol_version
    assert version.components == tuple(server.version)

    message_id, buffer = _read(server.answer(_their_request(4), sender))
    assert message_id == 5
    descriptions = DataDescriptions.read_from_buffer(buffer, version)
    assert buffer.pointer == len(buffer.data)  # they read exactly what we wrote
    assert {(d.id_num, d.name) for d in descriptions.rigid_bodies} == {(1, "WT"), (2, "HT")}
    assert all(len(d.markers) == 4 for d in descriptions.rigid_bodies)
    if version >= Version(4, 2):
        assert all(d.quat is not None for d in descriptions.rigid_bodies)

    frame = server.simulator.frame(T0, 5_000_000_000)
    message_id, buffer = _read(ours.build_frame(frame, server.version))
    assert message_id == 7
    theirs = DataFrame.read_from_buffer(buffer, version)
    assert theirs.prefix.frame_number == frame.number
    assert [(b.id_num, b.tracking_valid) for b in theirs.rigid_bodies] == [(1, True), (2, True)]
    for their_body, body in zip(theirs.rigid_bodies, frame.rigid_bodies, strict=True):
        assert their_body.pos == pytest.approx(body.position_m, abs=1e-6)
        assert their_body.rot == pytest.approx(body.rotation, abs=1e-6)
        assert their_body.marker_error == pytest.approx(body.mean_error_m, rel=1e-6)
        _q, t = SCENARIO.world.pose("ART", {1: "WT", 2: "HT"}[their_body.id_num], T0)
        assert np.linalg.norm(np.array(their_body.pos) - t) < 0.005  # noise: 0.3 mm per axis
    assert theirs.suffix.stamp_camera_mid_exposure == frame.mid_exposure_ticks
    assert theirs.suffix.stamp_transmit == frame.transmit_ticks
    assert theirs.suffix.timestamp == pytest.approx(frame.timestamp_s)
    if server.version.at_least(4, 1):
        # natnet 0.3 does not read the 4.1 precision timestamp (the SDK's C++ sample does),
        # so it stops 8 bytes early and its params are misread; everything before agrees.
        assert len(buffer.data) - buffer.pointer == 8 + 4
    else:
        assert len(buffer.data) - buffer.pointer == 4  # the end-of-data tag, which it skips
        assert not theirs.suffix.tracked_models_changed


@pytest.mark.parametrize("server", [NatNetVersion(4, 1)], indirect=True, ids=str)
def test_their_keepalive_and_an_unknown_request(server):
    sender = ("127.0.0.1", 40001)
    server.answer(_their_request(0), sender)
    assert server.answer(_their_request(10), sender) is None
    reply = server.answer(_their_request(2, "TimelinePlay"), sender)
    assert ours.split_packet(reply)[0] == ours.NAT_UNRECOGNIZED_REQUEST
