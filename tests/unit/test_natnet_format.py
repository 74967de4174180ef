"""The NatNet format: packets laid out as the SDK's sample clients read them parse, for
NatNet 3.0 to 4.2; what the module builds parses back; hostile input raises only
NatNetFormatError."""

from __future__ import annotations

import contextlib
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.unit.natnet_sdk_layout import (
    sdk_connect_request,
    sdk_frame,
    sdk_model_definitions,
    sdk_server_info,
)
from ubitrack_agent.io.natnet import format as natnet
from ubitrack_agent.io.natnet.format import (
    Frame,
    NatNetFormatError,
    NatNetVersion,
    RigidBody,
    RigidBodyDescription,
    ServerInfo,
)

VERSIONS = [NatNetVersion(3, 0), NatNetVersion(3, 1), NatNetVersion(4, 0), NatNetVersion(4, 1)]
VERSIONS += [NatNetVersion(4, 2)]
BODIES = [
    (1, (0.5, 1.25, -0.75, 0.0, 0.0, 0.38268343, 0.92387953), 0.0004, True),
    (2, (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), 0.0, False),
    (5, (-1.5, 0.25, 2.0, 0.5, 0.5, 0.5, 0.5), 0.0011, True),
]


def _payload(packet: bytes, message_id: int) -> memoryview:
    got, payload = natnet.split_packet(packet)
    assert got == message_id
    return payload


@pytest.mark.parametrize("version", VERSIONS, ids=str)
def test_an_sdk_laid_out_frame_parses_with_every_other_section_skipped(version):
    packet = sdk_frame(version[:2], 4711, BODIES, stamps=(10, 20, 35), params=0x02)
    frame = natnet.parse_frame(_payload(packet, natnet.NAT_FRAMEOFDATA), version)
    assert frame.number == 4711
    assert [(b.id, b.tracking_valid) for b in frame.rigid_bodies] == [
        (1, True),
        (2, False),
        (5, True),
    ]
    first = frame.rigid_bodies[0]
    assert first.position_m == pytest.approx((0.5, 1.25, -0.75))
    assert first.rotation == pytest.approx((0.0, 0.0, 0.38268343, 0.92387953))
    assert first.mean_error_m == pytest.approx(0.0004)
    assert frame.timestamp_s == 12.5
    assert (frame.mid_exposure_ticks, frame.data_received_ticks, frame.transmit_ticks) == (
        10,
        20,
        35,
    )
    assert frame.models_changed and not frame.recording
    expected = {"marker sets": 1, "legacy markers": 2, "skeletons": 1, "labeled markers": 2}
    expected |= {"force plates": 1, "devices": 1}
    if version.at_least(4, 1):
        expected["assets"] = 1
        assert (frame.precision_seconds, frame.precision_fraction) == (1_700_000_000, 12345)
    assert frame.skipped == expected


@pytest.mark.parametrize("version", VERSIONS, ids=str)
def test_a_frame_without_the_end_of_data_tag_parses_too(version):
    """The SDK's Python samples stop at the params; PacketClient and libNatNet read the tag."""
    packet = sdk_frame(version[:2], 1, BODIES, end_tag=False)
    frame = natnet.parse_frame(_payload(packet, natnet.NAT_FRAMEOFDATA), version)
    assert len(frame.rigid_bodies) == 3


@pytest.mark.parametrize("version", VERSIONS, ids=str)
def test_sdk_laid_out_model_definitions_name_the_rigid_bodies(version):
    packet = sdk_model_definitions(version[:2], {1: "Head", 5: "Table"})
    models = natnet.parse_model_definitions(_payload(packet, natnet.NAT_MODELDEF), version)
    assert [(b.id, b.name) for b in models.rigid_bodies] == [(1, "Head"), (5, "Table")]
    assert models.rigid_bodies[0].offset_m == pytest.approx((0.0, 0.01, 0.0))
    assert len(models.rigid_bodies[0].marker_offsets_m) == 3
    assert models.other_datasets == 5  # marker set, skeleton, force plate, device, camera


def test_the_sdk_server_info_gives_versions_clock_and_connection():
    info = natnet.parse_server_info(_payload(sdk_server_info((4, 1, 0, 0)), 1))
    assert info == ServerInfo(
        "Motive",
        NatNetVersion(3, 1, 0, 0),
        NatNetVersion(4, 1, 0, 0),
        10_000_000,
        1511,
        True,
        "239.255.42.99",
    )


def test_a_pre_3_server_info_has_no_connection_tail():
    payload = b"Motive".ljust(256, b"\0") + bytes([1, 10, 0, 0, 2, 10, 0, 0])
    info = natnet.parse_server_info(payload)
    assert info.natnet_version == (2, 10, 0, 0) and info.clock_frequency_hz is None
    assert not natnet.supported(info.natnet_version)


def test_connect_requests_of_the_sdk_sample_of_libnatnet_and_of_old_clients():
    _, payload = natnet.split_packet(sdk_connect_request((4, 1, 0, 0)))
    assert natnet.parse_connect(payload) == (4, 1, 0, 0)
    _, payload = natnet.split_packet(natnet.build_connect("ubitrack", NatNetVersion(3, 1)))
    assert len(payload) == natnet.CONNECT_BYTES == 269
    assert natnet.parse_connect(payload) == (3, 1, 0, 0)
    assert natnet.parse_connect(natnet.split_packet(natnet.build_connect("x"))[1]) is None
    assert natnet.parse_connect(b"Ping\0") is None


@pytest.mark.parametrize("version", VERSIONS, ids=str)
def test_what_is_built_parses_back(version):
    frame = Frame(
        9,
        (RigidBody(3, (1.0, 2.0, 3.0), (0.0, 0.0, 0.0, 1.0), 0.001953125, True),),
        4.25,
        100,
        150,
        300,
        7 if version.at_least(4, 1) else 0,
        8 if version.at_least(4, 1) else 0,
        recording=True,
    )
    assert natnet.parse_frame(_payload(natnet.build_frame(frame, version), 7), version) == frame
    bodies = (RigidBodyDescription("HT", 3, -1, (0.0, 0.0, 0.0), ((0.0625, 0.0, 0.0),)),)
    built = natnet.build_model_definitions(bodies, version)
    assert natnet.parse_model_definitions(_payload(built, 5), version).rigid_bodies == bodies


def test_unsupported_versions_are_refused():
    for version in (NatNetVersion(2, 10), NatNetVersion(5, 0)):
        with pytest.raises(NatNetFormatError, match="not supported"):
            natnet.parse_frame(b"", version)


@pytest.mark.parametrize(
    ("packet", "message"),
    [
        (b"\x07", "no 4-byte header"),
        (struct.pack("<HH", 7, 10) + b"\0" * 4, "header says 10 payload bytes, got 4"),
    ],
)
def test_a_packet_whose_header_lies_is_refused(packet, message):
    with pytest.raises(NatNetFormatError, match=message):
        natnet.split_packet(packet)


def test_a_hostile_count_is_refused_before_any_work():
    payload = struct.pack("<ii", 1, 2**31 - 1)  # frame 1, 2^31-1 marker sets
    with pytest.raises(NatNetFormatError, match="marker sets count 2147483647 does not fit"):
        natnet.parse_frame(payload, NatNetVersion(3, 1))


def test_a_rigid_body_section_whose_size_disagrees_is_refused():
    packet = bytearray(sdk_frame((4, 1), 1, BODIES))
    # the rigid-body section's size field follows frame number and two empty-ish sections
    _, payload = natnet.split_packet(bytes(packet))
    good = natnet.parse_frame(payload, NatNetVersion(4, 1))
    assert len(good.rigid_bodies) == 3
    offset = 4 + 4 + 4 + (5 + 4 + 24) + 4 + 4 + 24  # number, marker set section, legacy section
    assert struct.unpack_from("<ii", payload, offset) == (3, 3 * natnet.RIGID_BODY_BYTES)
    struct.pack_into("<i", packet, 4 + offset + 4, 3 * natnet.RIGID_BODY_BYTES - 2)
    with pytest.raises(NatNetFormatError, match="3 rigid bodies take 114 bytes, not 112"):
        natnet.parse_frame(natnet.split_packet(bytes(packet))[1], NatNetVersion(4, 1))


def test_non_finite_poses_and_bad_strings_are_refused():
    frame = Frame(1, (RigidBody(1, (float("nan"), 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)),))
    built = natnet.build_frame(frame, NatNetVersion(3, 1))
    with pytest.raises(NatNetFormatError, match="NaN or infinity"):
        natnet.parse_frame(natnet.split_packet(built)[1], NatNetVersion(3, 1))
    models = struct.pack("<ii", 1, 1) + b"\xff\xfe\0" + b"\0" * 24
    with pytest.raises(NatNetFormatError, match="not UTF-8"):
        natnet.parse_model_definitions(models, NatNetVersion(3, 1))
    with pytest.raises(NatNetFormatError, match="no terminating NUL"):
        natnet.parse_model_definitions(struct.pack("<ii", 1, 1) + b"HT", NatNetVersion(3, 1))


PARSERS = [
    lambda data: natnet.split_packet(data),
    lambda data: natnet.parse_server_info(data),
    lambda data: natnet.parse_connect(data),
    *(lambda data, v=v: natnet.parse_frame(data, v) for v in VERSIONS),
    *(lambda data, v=v: natnet.parse_model_definitions(data, v) for v in VERSIONS),
]


def _total(data: bytes) -> None:
    for parse in PARSERS:
        with contextlib.suppress(NatNetFormatError):
            parse(data)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=600))
def test_arbitrary_bytes_parse_or_raise_natnet_format_error_only(data):
    _total(data)


@settings(max_examples=300, deadline=None)
@given(
    st.sampled_from(VERSIONS),
    st.integers(0, 2000),
    st.integers(0, 255),
    st.integers(0, 2000),
)
def test_corrupted_sdk_packets_parse_or_raise_natnet_format_error_only(
    version, position, value, cut
):
    for packet in (
        sdk_frame(version[:2], 1, BODIES),
        sdk_model_definitions(version[:2], {1: "Head"}),
    ):
        payload = bytearray(packet[4:])
        payload[position % len(payload)] = value
        for data in (bytes(payload), bytes(payload[: cut % len(payload)])):
            with contextlib.suppress(NatNetFormatError):
                natnet.parse_frame(data, version)
            with contextlib.suppress(NatNetFormatError):
                natnet.parse_model_definitions(data, version)
