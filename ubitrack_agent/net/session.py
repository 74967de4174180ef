"""Open a zenoh session from :class:`~ubitrack_agent.net.config.Settings`.

The only place that turns settings into a ``zenoh.Config``. Callers own the session and must
close it (``with open_session(s) as session:``), as zenoh-python's documentation asks.
"""

from __future__ import annotations

import json

import zenoh

from ubitrack_agent.net.config import Settings


def zenoh_config(settings: Settings) -> zenoh.Config:
    """A ``zenoh.Config`` carrying exactly the options of ``settings``."""
    config = zenoh.Config()
    for path, value in settings.zenoh_options().items():
        config.insert_json5(path, json.dumps(value))
    return config


def open_session(settings: Settings) -> zenoh.Session:
    """Open a session; with multicast off and explicit endpoints this takes milliseconds."""
    return zenoh.open(zenoh_config(settings))
