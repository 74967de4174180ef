"""The layout of a recording (see the package docstring): profile, topics, encodings, channel
metadata, and the error every malformed recording raises. Pure: no MCAP library needed."""

from __future__ import annotations

import json

PROFILE = "ubitrack"
"""The MCAP profile of a recording: a file with another is not one."""
FORMAT_VERSION = "1"
"""The version of this layout, in every channel's metadata."""

ANNOUNCEMENTS_TOPIC = "/ubitrack/announcements"
DATA_TOPIC_PREFIX = "/ubitrack/data/"
TRANSFORM_TOPIC_PREFIX = "/ubitrack/tf/"

ANNOUNCEMENT_SCHEMA_NAME = "ubitrack.Announcement"
ANNOUNCEMENT_SCHEMA = json.dumps(
    {
        "title": ANNOUNCEMENT_SCHEMA_NAME,
        "description": "A provider announced (its SRG fragment, docs/protocol.md) or withdrawn",
        "type": "object",
        "properties": {
            "event": {"enum": ["announced", "withdrawn"]},
            "provider": {"type": "string"},
            "fragment": {"type": "object"},
        },
        "required": ["event", "provider"],
    },
    sort_keys=True,
).encode()
"""The JSON schema of the announcement channel's messages (MCAP schema encoding
``jsonschema``)."""

TRANSFORM_SCHEMA_NAME = "foxglove.FrameTransform"


class RecordingError(ValueError):
    """A recording that cannot be read or replayed; the message says where and why."""


def data_topic(edge_id: str) -> str:
    """The measurement channel's topic of measured edge ``<provider>/<name>``."""
    return DATA_TOPIC_PREFIX + edge_id


def transform_topic(edge_id: str) -> str:
    """The ``foxglove.FrameTransform`` channel's topic of measured edge ``edge_id``."""
    return TRANSFORM_TOPIC_PREFIX + edge_id
