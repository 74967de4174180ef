"""The one rule for names: frames, providers, edge names, instances and domains.

Every such name ends up inside a zenoh key expression (``docs/protocol.md``), so it must be a
literal key chunk that can never widen a subscription: letters, digits and ``_.-+:=%~^!``
only. That excludes zenoh's wildcards (``*``, ``$``), selector syntax (``#``, ``?``), the
admin space (``@``), the chunk separator ``/``, whitespace and non-ASCII characters. The SRG
(``ubitrack_agent.graph.srg``) and the key builder (``ubitrack_agent.net.keys``) both use it,
so a setup that plans offline also runs live.
"""

from __future__ import annotations

import re
from typing import Any

_NAME = re.compile(r"^[A-Za-z0-9_.\-+:=%~^!]+$")
ALLOWED = "letters, digits and _.-+:=%~^!"


def check_name(name: Any) -> str:
    """Return ``name`` if it follows the rule (see the module docstring), else ``ValueError``."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"must be a non-empty string, got {name!r}")
    if not _NAME.match(name):
        raise ValueError(f"{name!r} may only contain {ALLOWED}")
    return name
