"""The one rule for names: frames, providers, edge names, instances and domains.

Every such name ends up inside a zenoh key expression (``docs/protocol.md``), so it must be a
literal key chunk that can never widen a subscription: letters, digits and ``_.-+:=%~^!``
only. That excludes zenoh's wildcards (``*``, ``$``), selector syntax (``#``, ``?``), the
admin space (``@``), the chunk separator ``/``, whitespace and non-ASCII characters. The SRG
(``ubitrack_agent.graph.srg``) and the key builder (``ubitrack_agent.net.keys``) both use it,
so a setup that plans offline also runs live. A name is at most :data:`MAX_NAME_CHARS`
characters long.
"""

from __future__ import annotations

import re
import reprlib
from typing import Any

_NAME = re.compile(r"^[A-Za-z0-9_.\-+:=%~^!]+$")
ALLOWED = "letters, digits and _.-+:=%~^!"
MAX_NAME_CHARS = 128
"""Longest name; keys hold several names, and names come from the network."""
_SHOWN = reprlib.Repr()
_SHOWN.maxstring = _SHOWN.maxother = 60


def shown(value: Any) -> str:
    """A short ``repr`` of ``value`` for an error message, whatever it is (a huge integer,
    string or deeply nested list from the network): at most about 60 characters."""
    if isinstance(value, int) and abs(value) >= 10**50:
        return f"an integer of {value.bit_length()} bits"
    return _SHOWN.repr(value)


def check_name(name: Any) -> str:
    """Return ``name`` if it follows the rule (see the module docstring), else ``ValueError``."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"must be a non-empty string, got {shown(name)}")
    if len(name) > MAX_NAME_CHARS:
        raise ValueError(f"{shown(name)} is longer than {MAX_NAME_CHARS} characters")
    if not _NAME.match(name):
        raise ValueError(f"{shown(name)} may only contain {ALLOWED}")
    return name


LABEL_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")
"""A host label (``camera``, ``gpu``, ``hmd``): a name without ``+``, which joins labels in a
query key (``net.keys``)."""


def check_label(label: Any) -> str:
    """Return ``label`` if it is a host label (:data:`LABEL_PATTERN`), else ``ValueError``."""
    if not isinstance(label, str) or not LABEL_PATTERN.match(label):
        raise ValueError(
            f"{shown(label)} is no label (letters, digits and _.- , at most 64 characters)"
        )
    return label


def parse_labels(text: str) -> frozenset[str]:
    """Comma-separated labels (a command-line option), each checked; ``ValueError`` naming the
    first that is no label."""
    return frozenset(check_label(part.strip()) for part in text.split(",") if part.strip())
