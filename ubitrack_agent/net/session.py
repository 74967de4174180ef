"""Open a zenoh session from :class:`~ubitrack_agent.net.config.Settings`.

The only place that turns settings into a ``zenoh.Config``. Callers own the session and must
close it (``with open_session(s) as session:``), as zenoh-python's documentation asks.

A zenoh configuration file named by ``ZENOH_CONFIG`` (zenoh's own variable, as
``zenoh.Config.from_env`` reads it) is the base the settings are written over: a deployment
tunes zenoh's transport there (batching, queues, per-key publication QoS: ``qos/publication``,
which overrides what a publisher was declared with) without a setting of ours for each. The
variable is inherited by every process a host manager or an agent starts, so one file tunes a
host; the benchmarks switch zenoh's options this way (``docs/performance.md``, "Zenoh's own
options on the data path").
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping

import zenoh

from ubitrack_agent.net.config import Settings

CONFIG_VARIABLE = "ZENOH_CONFIG"
"""The environment variable naming a zenoh configuration file (JSON5) to start from."""


def zenoh_config(settings: Settings, env: Mapping[str, str] | None = None) -> zenoh.Config:
    """A ``zenoh.Config`` carrying the options of ``settings``, over the file that
    ``ZENOH_CONFIG`` in ``env`` (this process's environment by default) names, if any."""
    path = (os.environ if env is None else env).get(CONFIG_VARIABLE)
    config = zenoh.Config.from_file(path) if path else zenoh.Config()
    for key, value in settings.zenoh_options().items():
        config.insert_json5(key, json.dumps(value))
    return config


def open_session(settings: Settings) -> zenoh.Session:
    """Open a session; with multicast off and explicit endpoints this takes milliseconds."""
    return zenoh.open(zenoh_config(settings))
