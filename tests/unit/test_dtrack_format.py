"""DTrack2 ASCII format: exact lines from A.R.T.'s documentation, round trips, malformed input."""

from __future__ import annotations

import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ubitrack_agent.io.dtrack.format import (
    Body6D,
    DTrackFormatError,
    DTrackFrame,
    Marker3D,
    encode_frame,
    parse_frame,
)

# The 6d example of the Flystick manual, appendix B.2 (field notes, section 6).
EXAMPLE_6D = (
    "6d 1 [0 1.000][326.848 -187.216 109.503 -160.4704 -3.6963 -7.0913]"
    "[-0.940508 -0.339238 -0.019025 0.333599 -0.932599 0.137735 -0.064467 0.123194 0.990286]"
)
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


def test_untracked_bodies_are_absent_and_unknown_lines_skipped():
    frame = parse_frame(b"fr 3\n6dcal 4\n6d 0\n6df2 1 0\ngl 0\n3d 0\n")
    assert frame.bodies == () and frame.markers == () and frame.calibrated_bodies == 4
    assert frame.timestamp_s is None


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
        (b"fr 1\n6d 1 [0 1.000][1 2 3 0 0][1 0 0 0 1 0 0 0 1]", "expected 6 numbers"),
        (b"fr 1\n6d 1 [0 1.000][1 2 3 0 0 0][1 0 0 0 1 0 0 0 2]", "not a rotation matrix"),
        (b"fr 1\n6d 1 [0 1.000][1 2 a 0 0 0][1 0 0 0 1 0 0 0 1]", "not a number"),
        (b"fr 1\n6d 1 [-1 1.000][1 2 3 0 0 0][1 0 0 0 1 0 0 0 1]", "id: must be >= 0"),
        (b"fr 1\n6d 1 [0 1.000] junk [1 2 3 0 0 0][1 0 0 0 1 0 0 0 1]", "outside [...]"),
        (b"fr 1\n6d 1 [0 1.000][1 2 3 0 0 0][1 0 0 0 1 0 0 0 1", "outside [...]"),
        (b"fr 1\n6d 99999999", "exceeds"),
        (b"fr 1\n3d 1 [0 1.000][1 2 3]", "id: must be >= 1"),
        (b"fr 1\n3d 1 [1][1 2 3]", "expected [id quality]"),
        (b"fr 1\nfr 2", "appears twice"),
        (b"fr 1\n\xff", "not ASCII"),
    ],
)
def test_malformed_datagrams_raise_one_error_type(datagram, message):
    with pytest.raises(DTrackFormatError, match=re.escape(message)):
        parse_frame(datagram)
