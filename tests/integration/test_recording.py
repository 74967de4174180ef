"""``ubitrack record`` and ``ubitrack replay`` on the live figure-1 set-up (issue 30, item 3):
record the demo's sensors while ``C -> HT`` is calibrated live, replay the file into a fresh
agent with no simulator running, and calibrate there: the two results agree within 1 mm and
0.1 degree, ``C -> A`` is tracked on the replay, and the file opens with ``mcap``'s own reader
and its ``foxglove.FrameTransform`` channel decodes with ``mcap-protobuf-support``'s decoder
(code nobody here wrote). The 30 s comparison is ``bench/recording_bench.py``'s.
"""

from __future__ import annotations

import pytest

pytest.importorskip("mcap", reason='needs the mcap extra: pip install "ubitrack-agent[mcap]"')
mcap_protobuf = pytest.importorskip(
    "mcap_protobuf.decoder", reason="needs mcap-protobuf-support (the test extra)"
)

from mcap.reader import make_reader  # noqa: E402

from tests.integration.recording_helpers import (  # noqa: E402
    PROVIDERS,
    difference,
    record_live,
    replay_into_fresh_agent,
)
from ubitrack_agent.core import decode  # noqa: E402

RECORD_S = 25.0
"""Long enough for the live calibration (about 10 s) and, on the replay, the agent's planning,
the same calibration and a few seconds of C->A."""


def test_recording_replays_into_a_fresh_agent(processes, tmp_path):
    path = tmp_path / "figure1.mcap"
    live = record_live(processes, path, RECORD_S)
    assert live["recorder_status"] == 0, live["recorder"]
    announced = {line["provider"] for line in live["recorder"] if line["event"] == "announced"}
    assert set(PROVIDERS) <= announced
    finished = live["recorder"][-1]
    assert finished["event"] == "finished" and finished["measurements"] > 1000, finished
    assert finished.get("rejected_samples", 0) == 0 and finished.get("rejected_fragments", 0) == 0

    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[mcap_protobuf.DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count > 1000  # finished
        topics = {channel.topic for channel in summary.channels.values()}
        assert "/ubitrack/tf/ART/ART_HT" in topics and "/ubitrack/data/ART/ART_HT" in topics
        poses = [
            decode(message.data)
            for _, _, message in reader.iter_messages(topics=["/ubitrack/data/ART/ART_HT"])
        ]
        transforms = [
            decoded
            for _, _, _, decoded in reader.iter_decoded_messages(topics=["/ubitrack/tf/ART/ART_HT"])
        ]
    assert len(transforms) == len(poses) > 100
    first, pose = transforms[0], poses[0]
    assert (
        first.parent_frame_id,
        first.child_frame_id,
        first.timestamp.ToNanoseconds(),
        [first.translation.x, first.translation.y, first.translation.z],
        [first.rotation.x, first.rotation.y, first.rotation.z, first.rotation.w],
    ) == ("ART", "HT", pose.timestamp_ns, pose.translation.tolist(), pose.rotation.tolist())

    replayed = replay_into_fresh_agent(processes, path)
    mm, deg = difference(live["calibration"]["value"], replayed["calibration"]["value"])
    tracked = replayed["tracked_samples"]
    print(f"live vs replay C->HT: {mm:.3f} mm, {deg:.4f} deg; C->A samples {tracked}")
    assert mm < 1.0 and deg < 0.1
    assert tracked > 30
    loaded = replayed["replay"][0]
    assert loaded["event"] == "loaded" and loaded["timestamps"] == "shifted"
