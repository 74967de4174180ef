"""NatNet packets laid out field by field as the NatNet SDK's sample clients read them.

Written from the SDK's ``Samples/PythonClient/NatNetClient.py`` (3.1 and the 4.x sample:
``__unpack_mocap_data``, ``__unpack_data_descriptions``, ``__unpack_server_info``,
``send_request``) and ``Samples/PacketClient/PacketClient.cpp`` (the end-of-data tag, the
4.1 precision timestamp), independently of ``ubitrack_agent.io.natnet.format``: each section
here is built with its own ``struct`` calls, in the order the samples unpack them, and every
section the adapter skips is non-empty, so a parser that miscounts one misreads what follows.
"""

from __future__ import annotations

import struct


def _at_least(version: tuple[int, int], major: int, minor: int) -> bool:
    return version >= (major, minor)


def _with_size(version: tuple[int, int], count: int, body: bytes) -> bytes:
    """``int32 count`` and, from 4.1 (the samples' ``__unpack_data_size``), ``int32`` bytes."""
    sized = _at_least(version, 4, 1)
    return struct.pack("<i", count) + (struct.pack("<i", len(body)) if sized else b"") + body


def sdk_connect_request(version: tuple[int, int, int, int]) -> bytes:
    """``send_request(NAT_CONNECT)`` of the SDK's 4.x Python sample: 270 bytes, "Ping" at 0,
    0 at 264, the requested version at 265-268, then a NUL; size 271."""
    command = [0] * 270
    command[0:4] = b"Ping"
    command[265:269] = version
    payload = bytes(command) + b"\0"
    return struct.pack("<HH", 0, len(payload)) + payload


def sdk_server_info(natnet: tuple[int, int, int, int], frequency: int = 10_000_000) -> bytes:
    """``NAT_SERVERINFO``: ``sSender_Server`` (name[256], Version[4], NatNetVersion[4],
    HighResClockFrequency, DataPort, IsMulticast, MulticastGroupAddress[4])."""
    payload = b"Motive".ljust(256, b"\0") + bytes([3, 1, 0, 0]) + bytes(natnet)
    payload += struct.pack("<Q", frequency) + struct.pack("<H", 1511) + b"\x01"
    payload += bytes([239, 255, 42, 99])
    return struct.pack("<HH", 1, len(payload)) + payload


def _rigid_body_description(version: tuple[int, int], name: str, body_id: int) -> bytes:
    data = name.encode() + b"\0" + struct.pack("<i", body_id) + struct.pack("<i", -1)
    data += struct.pack("<fff", 0.0, 0.01, 0.0)
    if _at_least(version, 4, 2):  # __unpack_rigid_body_descript_4_2_to_current
        data += struct.pack("<ffff", 0.0, 0.0, 0.0, 1.0)
    offsets = [(0.05, 0.0, 0.0), (0.0, 0.05, 0.0), (0.0, 0.0, 0.05)]
    data += struct.pack("<i", len(offsets))
    for offset in offsets:
        data += struct.pack("<fff", *offset)
    for label in range(len(offsets)):
        data += struct.pack("<i", label + 1)
    if _at_least(version, 4, 0):
        for index in range(len(offsets)):
            data += f"{name}_{index + 1}".encode() + b"\0"
    return data


def sdk_model_definitions(version: tuple[int, int], bodies: dict[int, str]) -> bytes:
    """``NAT_MODELDEF`` with a marker set, ``bodies`` (id -> name), a skeleton of two bones,
    a force plate, a device and a camera, in the samples' layouts per type."""
    datasets: list[tuple[int, bytes]] = []
    marker_set = b"Wand\0" + struct.pack("<i", 2) + b"Wand_1\0Wand_2\0"
    datasets.append((0, marker_set))
    for body_id, name in bodies.items():
        datasets.append((1, _rigid_body_description(version, name, body_id)))
    skeleton = b"Actor\0" + struct.pack("<i", 7) + struct.pack("<i", 2)
    skeleton += _rigid_body_description(version, "Hip", 1) + _rigid_body_description(
        version, "Spine", 2
    )
    datasets.append((2, skeleton))
    plate = struct.pack("<i", 1) + b"FP-01\0" + struct.pack("<ff", 0.6, 0.4)
    plate += struct.pack("<fff", 0.0, 0.0, 0.0)
    plate += struct.pack("<144f", *range(144)) + struct.pack("<12f", *range(12))
    plate += struct.pack("<iii", 1, 0, 2) + b"Fx\0Fy\0"
    datasets.append((3, plate))
    device = struct.pack("<i", 3) + b"EMG\0" + b"SN-3\0" + struct.pack("<ii", 1, 0)
    device += struct.pack("<i", 1) + b"ch1\0"
    datasets.append((4, device))
    camera = b"Cam 1\0" + struct.pack("<fff", 1.0, 2.0, 3.0) + struct.pack("<ffff", 0, 0, 0, 1)
    datasets.append((5, camera))
    payload = struct.pack("<i", len(datasets))
    for kind, data in datasets:
        payload += struct.pack("<i", kind)
        if _at_least(version, 4, 1):
            payload += struct.pack("<i", len(data))
        payload += data
    return struct.pack("<HH", 5, len(payload)) + payload


def _rigid_body(body_id: int, pose: tuple[float, ...], error: float, valid: bool) -> bytes:
    """``__unpack_rigid_body_3_and_above``: id, position, quaternion, mean error, params."""
    return (
        struct.pack("<i", body_id)
        + struct.pack("<fff", *pose[:3])
        + struct.pack("<ffff", *pose[3:])
        + struct.pack("<f", error)
        + struct.pack("<h", 1 if valid else 0)
    )


def sdk_frame(
    version: tuple[int, int],
    number: int,
    bodies: list[tuple[int, tuple[float, ...], float, bool]],
    stamps: tuple[int, int, int] = (1000, 1500, 2000),
    params: int = 0,
    end_tag: bool = True,
) -> bytes:
    """``NAT_FRAMEOFDATA`` in ``__unpack_mocap_data``'s order, every other section filled."""
    payload = struct.pack("<i", number)
    marker_set = b"Wand\0" + struct.pack("<i", 2) + struct.pack("<6f", *range(6))
    payload += _with_size(version, 1, marker_set)
    payload += _with_size(version, 2, struct.pack("<6f", 1, 2, 3, 4, 5, 6))  # legacy markers
    payload += _with_size(version, len(bodies), b"".join(_rigid_body(*body) for body in bodies))
    bones = _rigid_body(65537, (0, 0, 0, 0, 0, 0, 1), 0.0, True) * 2
    payload += _with_size(version, 1, struct.pack("<ii", 7, 2) + bones)  # a skeleton
    if _at_least(version, 4, 1):  # assets: id, rigid bodies, markers
        asset = struct.pack("<ii", 9, 1) + _rigid_body(9, (0, 0, 0, 0, 0, 0, 1), 0.0, True)
        asset += struct.pack("<i", 1) + struct.pack("<i3ffhf", 3, 0, 0, 0, 0.01, 0, 0.0)
        payload += _with_size(version, 1, asset)
    labeled = struct.pack("<i3ffhf", 65537, 1.0, 2.0, 3.0, 0.014, 0x02, 0.0001)
    payload += _with_size(version, 2, labeled * 2)
    plate = struct.pack("<ii", 1, 2) + (struct.pack("<i", 3) + struct.pack("<3f", 1, 2, 3)) * 2
    payload += _with_size(version, 1, plate)
    device = struct.pack("<ii", 3, 1) + struct.pack("<i", 1) + struct.pack("<f", 0.5)
    payload += _with_size(version, 1, device)
    payload += struct.pack("<II", 0x01020304, 5)  # timecode, subframe
    payload += struct.pack("<d", 12.5)
    payload += struct.pack("<QQQ", *stamps)
    if _at_least(version, 4, 1):  # PacketClient: precision timestamps from 4.1
        payload += struct.pack("<II", 1_700_000_000, 12345)
    payload += struct.pack("<h", params)
    if end_tag:
        payload += struct.pack("<i", 0)
    return struct.pack("<HH", 7, len(payload)) + payload
