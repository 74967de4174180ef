"""The wire format as ``docs/protocol.md`` documents it ("Measurements on the wire"): an
application with plain zenoh, msgpack and numpy, no project code, asks for a relation and
decodes its samples; they are the trackers' truth (issue 14, item 4)."""

from __future__ import annotations

import json
import queue

import msgpack
import numpy as np
import pytest
import zenoh
from scipy.spatial.transform import Rotation

from tests.integration.test_agent import Setup, opened
from ubitrack_agent.sim_trackers.exact_tracker import true_wt_ht

pytestmark = pytest.mark.integration


@pytest.fixture
def setup(processes):
    yield from opened(processes)


def decode(payload: bytes) -> dict:
    """A pose sample as the documentation decodes it."""
    message = msgpack.unpackb(payload, raw=False)
    shapes = {"rotation": (4,), "translation": (3,), "covariance": (6, 6)}
    return {
        "type": message["type"],
        "t": message["t"],
        **{
            field: np.frombuffer(message[field], "<f8").reshape(shape)
            for field, shape in shapes.items()
            if field in message
        },
    }


def test_a_plain_zenoh_application_decodes_a_relation_as_documented(setup: Setup):
    setup.start_agent()
    setup.tracker("art", "ART", 30.0, 2.0)
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{setup.port}"]))
    config.insert_json5("scouting/multicast/enabled", "false")
    root = f"ubitrack/{setup.domain}"
    samples: queue.Queue[bytes] = queue.Queue()
    encodings: set[str] = set()
    with zenoh.open(config) as session:
        query = f"{root}/query/WT/HT/6D/dynamic/laptop/plain-app"
        token = session.liveliness().declare_token(query)
        subscriber = session.declare_subscriber(
            f"{root}/relation/WT/HT/6D/dynamic",
            lambda s: (encodings.add(str(s.encoding)), samples.put(s.payload.to_bytes())),
        )
        received = [decode(samples.get(timeout=30)) for _ in range(20)]
        assert encodings == {"application/msgpack"}
        for key in (f"{root}/agent/status", f"{root}/answer/WT/HT/6D/dynamic"):
            (reply,) = list(session.get(key, timeout=5.0))
            assert str(reply.ok.encoding) == "application/json"
            json.loads(reply.ok.payload.to_bytes())  # what a generic tool may read
        subscriber.undeclare()
        token.undeclare()
    for sample in received:
        assert sample["type"] in ("Pose", "ErrorPose")
        rotation, translation = true_wt_ht(sample["t"])
        np.testing.assert_allclose(sample["translation"], translation, atol=1e-6)
        angle = Rotation.from_quat(sample["rotation"]).inv() * Rotation.from_quat(rotation)
        assert angle.magnitude() < 1e-6
