"""DTrack2 ASCII format: exact lines from A.R.T.'s documentation, round trips, the SDK's
leniency (extra values, untracked items, NUL, unknown lines), malformed input, any bytes."""

from __future__ import annotations

import contextlib
import re

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from ubitrack_agent.io.dtrack.format import (
    Body6D,
    DTrackFormatError,
    DTrackFrame,
    Marker3D,
    UnixTime,
    encode_frame,
    parse_frame,
)

# The 6d example of the Flystick manual, appendix B.2 (field notes, section 6).
EXAMPLE_6D = (
    "6d 1 [0 1.000][326.848 -187.216 109.503 -160.4704 -3.6963 -7.0913]"
    "[-0.940508 -0.339238 -0.019025 0.333599 -0.932599 0.137735 -0.064467 0.123194 0.990286]"
)
# The 6df (old Flystick) example of the same appendix: id 0, quality 1, buttons 2.
EXAMPLE_6DF = (
    "6df 1 [0 1.000 2][261.103 116.520 41.085 19.6522 -57.3530 116.5992]"
    "[-0.241543 0.968868 -0.054332 -0.482366 -0.168461 -0.859619 -0.842010 -0.181427 0.508039]"
)
IDENTITY = "[1 0 0 0 1 0 0 0 1]"
ZERO_MATRIX = "[0 0 0 0 0 0 0 0 0]"
EXAMPLE = f"fr 21753\r\nts 39596.024831\r\n6dcal 2\r\n{EXAMPLE_6D}\r\n3d 1 [1 1.000][10 20 30]\r\n"


def test_parses_the_documented_example_exactly():
    frame = parse_frame(EXAMPLE.encode())
    assert frame.frame == 21753
    assert frame.timestamp_s == 39596.024831
    assert frame.calibrated_bodies == 2
    (body,) = frame.bodies
    assert body.id == 0 and body.quality == 1.0
    np.testing.assert_array_equal(body.position_mm, [326.848, -187.216, 109.503])
    # Column-wise: b0 b1 b2 is the first column.
    np.testing.assert_array_equal(body.rotation[:, 0], [-0.940508, -0.339238, -0.019025])
    np.testing.assert_array_equal(body.rotation[0], [-0.940508, 0.333599, -0.064467])
    (marker,) = frame.markers
    assert marker.id == 1
    np.testing.assert_array_equal(marker.position_mm, [10, 20, 30])


def test_encoder_writes_the_documented_line_for_the_documented_body():
    body = parse_frame(f"fr 1\n{EXAMPLE_6D}".encode()).bodies[0]
    lines = encode_frame(DTrackFrame(21753, 39596.024831, 2, (body,))).decode().split("\r\n")
    assert lines[:4] == ["fr 21753", "ts 39596.024831", "6dcal 2", EXAMPLE_6D]
    assert lines[4:] == ["3d 0", ""]


def test_round_trip_within_the_printed_precision():
    rng = np.random.default_rng(3)
    bodies = tuple(
        Body6D(i, 1.0, rng.uniform(-3000, 3000, 3), Rotation.random(rng=rng).as_matrix())
        for i in (0, 4)
    )
    markers = (Marker3D(7, 0.5, np.array([1.2345, -0.5, 1000.0])),)
    frame = DTrackFrame(42, 86399.123456, 5, bodies, markers)
    parsed = parse_frame(encode_frame(frame))
    assert (parsed.frame, parsed.timestamp_s, parsed.calibrated_bodies) == (42, 86399.123456, 5)
    for got, want in zip(parsed.bodies, bodies, strict=True):
        assert got.id == want.id
        np.testing.assert_allclose(got.position_mm, want.position_mm, atol=5e-4)
        np.testing.assert_allclose(got.rotation, want.rotation, atol=5e-7)
    np.testing.assert_allclose(parsed.markers[0].position_mm, [1.2345, -0.5, 1000.0], atol=5e-4)
    assert parsed.markers[0].id == 7 and parsed.markers[0].quality == 0.5


def test_parses_the_documented_flystick_example_exactly():
    (flystick,) = parse_frame(f"fr 1\r\n{EXAMPLE_6DF}\r\n".encode()).flysticks
    assert flystick.id == 0 and flystick.quality == 1.0
    np.testing.assert_array_equal(flystick.position_mm, [261.103, 116.520, 41.085])
    np.testing.assert_array_equal(flystick.rotation[:, 0], [-0.241543, 0.968868, -0.054332])
    # Its angles are its matrix's, but listed in the opposite order to the 6d example's
    # (eta, theta, phi): one more reason to ignore them, as ART recommends and the parser does.
    angles = Rotation.from_matrix(flystick.rotation).as_euler("zyx", degrees=True)
    np.testing.assert_allclose(angles[::-1], [19.6522, -57.3530, 116.5992], atol=2e-3)


def test_untracked_bodies_are_absent_and_unknown_lines_skipped():
    frame = parse_frame(b"fr 3\n6dcal 4\n6d 0\n6df2 1 0\ngl 0\n3d 0\nzz 1 [2]\ngl 1\n")
    assert frame.bodies == () and frame.markers == () and frame.flysticks == ()
    assert frame.calibrated_bodies == 4 and frame.timestamp_s is None
    assert frame.skipped_lines == ("gl", "zz")  # each type once, in order


def test_extra_values_in_a_block_are_ignored_as_the_sdk_does():
    frame = parse_frame(
        b"fr 1\n6d 1 [0 1.000 extra][1 2 3 0 0 0 7][1 0 0 0 1 0 0 0 1 9]\n3d 1 [1 1.0 x][4 5 6 0]"
    )
    (body,) = frame.bodies
    assert body.id == 0 and body.quality == 1.0
    np.testing.assert_array_equal(body.position_mm, [1, 2, 3])
    np.testing.assert_array_equal(body.rotation, np.eye(3))
    np.testing.assert_array_equal(frame.markers[0].position_mm, [4, 5, 6])


def test_an_untracked_body_is_skipped_and_the_others_published():
    frame = parse_frame(
        f"fr 1\n6d 3 [0 1.000][0 0 0 0 0 0]{ZERO_MATRIX}"  # zero matrix: untracked
        f"[1 1.000][1 2 3 0 0 0]{IDENTITY}"
        f"[2 -1.000][0 0 0 0 0 0]{IDENTITY}\n3d 1 [1 -1.000][0 0 0]".encode()  # quality < 0
    )
    assert [body.id for body in frame.bodies] == [1] and frame.markers == ()


@pytest.mark.parametrize(
    "datagram", [b"fr 7\x00", b"fr 7\r\n6d 0\r\n\x00", b"fr 7\n\x00\xffjunk 6d 2 ["]
)
def test_a_datagram_ends_at_its_first_nul(datagram):
    assert parse_frame(datagram).frame == 7


def test_hybrid_bodies_are_published_unless_their_status_is_none():
    frame = parse_frame(
        f"fr 1\n6di 3 [0 3 0.100][1 2 3]{IDENTITY}[1 0 0.000][0 0 0]{ZERO_MATRIX}"
        f"[4 1 2.5][4 5 6]{IDENTITY}".encode()
    )
    assert [(b.id, b.quality) for b in frame.hybrid_bodies] == [(0, None), (4, None)]
    np.testing.assert_array_equal(frame.hybrid_bodies[1].position_mm, [4, 5, 6])
    assert frame.bodies == ()


def test_new_flysticks_with_buttons_and_joysticks():
    frame = parse_frame(
        f"fr 1\n6df2 3 2 [0 1.000 6 2][1 2 3]{IDENTITY}[5 0.5 -1.0]"
        f"[1 -1.000 40 0][0 0 0]{ZERO_MATRIX}[0 0]".encode()
    )
    (flystick,) = frame.flysticks
    assert flystick.id == 0 and flystick.quality == 1.0
    np.testing.assert_array_equal(flystick.position_mm, [1, 2, 3])


def test_measurement_tools_old_and_new():
    (tool,) = parse_frame(f"fr 1\n6dmt 1 [0 0.900 1][1 2 3]{IDENTITY}".encode()).tools
    assert (tool.id, tool.quality, tool.position_covariance_mm2) == (0, 0.9, None)
    tools = parse_frame(
        f"fr 1\n6dmt2 2 2 [0 1.000 2 1.5][1 2 3]{IDENTITY}[3][0.04 0.01 0 0.09 0 0.16]"
        f"[1 -1.000 0 1.5][0 0 0]{ZERO_MATRIX}[][0 0 0 0 0 0]".encode()
    ).tools
    (tool,) = tools
    np.testing.assert_array_equal(
        tool.position_covariance_mm2, [[0.04, 0.01, 0], [0.01, 0.09, 0], [0, 0, 0.16]]
    )


def test_ts2_is_the_unix_time_and_latency():
    frame = parse_frame(b"fr 1\nts2 1763700000 123456 2500\nts 12.5\n")
    assert frame.unix_time == UnixTime(1_763_700_000_123_456_000, 2_500_000)
    assert frame.timestamp_s == 12.5


@pytest.mark.parametrize(
    ("datagram", "message"),
    [
        (b"", "does not start with an 'fr'"),
        (b"ts 12.5\nfr 1", "does not start with an 'fr'"),
        (b"fr x", "fr: expected an integer"),
        (b"fr -1", "fr: must be >= 0"),
        (b"fr 1\nts 90000.0", "not seconds since midnight"),
        (b"fr 1\nts nan", "NaN"),
        (b"fr 1\n6d 2 [0 1.000][1 2 3 0 0 0][1 0 0 0 1 0 0 0 1]", "count says 2 items"),
        (b"fr 1\n6d 1 [0 1.000][1 2][1 0 0 0 1 0 0 0 1]", "6d body 0 position: expected 3 values"),
        (b"fr 1\n6d 1 [0][1 2 3][1 0 0 0 1 0 0 0 1]", "6d body 0: expected 2 values, got 1"),
        (b"fr 1\n6d 1 [0 1.000][1 2 3][1 0 0 0 1 0 0 0]", "6d body 0 matrix: expected 9 values"),
        (b"fr 1\n6d 1 [0 -1.000][1 2 3][1 0 0 0 1 0 0 0]", "6d body 0 matrix: expected 9"),
        (b"fr 1\n6d 1 [0 1.000][1 2 3 0 0 0][1 0 0 0 1 0 0 0 2]", "not a rotation matrix"),
        (b"fr 1\n6d 1 [0 1.000][1 2 a 0 0 0][1 0 0 0 1 0 0 0 1]", "not a number"),
        (b"fr 1\n6d 1 [-1 1.000][1 2 3 0 0 0][1 0 0 0 1 0 0 0 1]", "id: must be >= 0"),
        (b"fr 1\n6d 1 [0 1.000] junk [1 2 3 0 0 0][1 0 0 0 1 0 0 0 1]", "outside [...]"),
        (b"fr 1\n6d 1 [0 1.000][1 2 3 0 0 0][1 0 0 0 1 0 0 0 1", "outside [...]"),
        (b"fr 1\n6d 99999999", "exceeds"),
        (b"fr 1\n3d 1 [0 1.000][1 2 3]", "id: must be >= 1"),
        (b"fr 1\n3d 1 [1][1 2 3]", "3d marker 0: expected 2 values, got 1"),
        (b"fr 1\n6di 1 [0 3][1 2 3][1 0 0 0 1 0 0 0 1]", "6di body 0: expected 3 values"),
        (b"fr 1\n6df 1 [0 1.000][1 2 3][1 0 0 0 1 0 0 0 1]", "6df Flystick 0: expected 3"),
        (b"fr 1\n6df 1 [1 1.000 0][1 2 3][1 0 0 0 1 0 0 0 1]", "id 1 where 0 is expected"),
        (b"fr 1\n6df2 1 [0 1 0 0][1 2 3][1 0 0 0 1 0 0 0 1][]", "6df2: expected 2 count(s)"),
        (b"fr 1\n6df2 1 1 [0 1 33 1][1 2 3][1 0 0 0 1 0 0 0 1][0 0]", "buttons: expected 3"),
        (b"fr 1\n6dmt2 1 1 [0 1 0 1][1 2 3][1 0 0 0 1 0 0 0 1][][0 0]", "covariance: expected 6"),
        (b"fr 1\n6dmt 1 [0 1 x][1 2 3][1 0 0 0 1 0 0 0 1]", "6dmt tool 0 buttons: expected an"),
        (b"fr 1\nts2 1 1000000 0", "ts2: 1000000 microseconds"),
        (b"fr 1\nts2 1 2", "ts2: expected 3 values"),
        (b"fr 1\n6df 0\n6df2 0 0", "line '6df2' appears twice (as '6df')"),
        (b"fr 1\nfr 2", "appears twice"),
        (b"fr 1\n\xff", "not ASCII"),
    ],
)
def test_malformed_datagrams_raise_one_error_type(datagram, message):
    with pytest.raises(DTrackFormatError, match=re.escape(message)):
        parse_frame(datagram)


TOKENS = [
    "fr", "ts", "ts2", "6dcal", "6d", "6di", "6df", "6df2", "6dmt", "6dmt2", "3d", "gl",
    " ", "\r\n", "\n", "\x00", "[", "]", "0", "1", "2", "-1", "33", "1.000", "-1.000",
    "nan", "1e400", "x", "99999", "0.5",
]  # fmt: skip


@given(st.binary(max_size=200))
def test_any_bytes_parse_or_raise_the_format_error(datagram):
    with contextlib.suppress(DTrackFormatError):
        parse_frame(datagram)


@given(st.lists(st.sampled_from(TOKENS), max_size=60))
def test_any_line_of_dtrack_tokens_parses_or_raises_the_format_error(tokens):
    try:
        frame = parse_frame(("fr 1\n" + " ".join(tokens)).encode())
    except DTrackFormatError:
        return
    for item in (*frame.bodies, *frame.hybrid_bodies, *frame.flysticks, *frame.tools):
        assert np.allclose(item.rotation @ item.rotation.T, np.eye(3), atol=1e-3)
