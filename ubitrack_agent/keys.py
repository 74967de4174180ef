"""Every zenoh key expression the middleware uses, built in this one module.

Layout (all below ``<prefix>/<domain>``, default ``ubitrack/default``)::

    <root>/data/<edge-id>            measurements of one SRG edge (msgpack, see core.codec)
    <root>/worker/<instance>         liveliness token of a running pattern worker
    <root>/control/<instance>        rewire / reconfigure a running worker (JSON, put)
    <root>/status/<instance>         a worker's counters (JSON, queryable)

Names that end up inside keys (frames, edge ids, domains) are checked chunk by chunk: no empty
chunks, no wildcards (``*``, ``$``), no ``#``/``?`` (selector syntax), no ``@`` (zenoh's
admin space) and no whitespace, so a hostile name can never widen a subscription.
"""

from __future__ import annotations

import re

_CHUNK = re.compile(r"^[A-Za-z0-9_.\-+:=%~^!]+$")
"""Characters allowed in one key chunk: a safe subset of what zenoh accepts."""


def validate_key_chunks(text: str, single_chunk: bool = False) -> str:
    """Return ``text`` if it is a safe literal key (one chunk if ``single_chunk``), else raise."""
    if not isinstance(text, str) or not text:
        raise ValueError("must be a non-empty string")
    chunks = text.split("/")
    if single_chunk and len(chunks) > 1:
        raise ValueError(f"{text!r} must not contain '/'")
    for chunk in chunks:
        if not chunk:
            raise ValueError(f"{text!r} has an empty chunk (leading, trailing or double '/')")
        if not _CHUNK.match(chunk):
            raise ValueError(
                f"{text!r}: chunk {chunk!r} may only contain letters, digits and _.-+:=%~^!"
            )
    return text


class KeySpace:
    """Builds the keys of one ``<prefix>/<domain>`` root."""

    def __init__(self, root: str) -> None:
        self.root = validate_key_chunks(root)

    def data(self, edge_id: str) -> str:
        """Key on which the measurements of edge ``edge_id`` flow."""
        return f"{self.root}/data/{validate_key_chunks(edge_id)}"

    def worker(self, instance: str) -> str:
        """Liveliness token of the worker running component ``instance``."""
        return f"{self.root}/worker/{validate_key_chunks(instance, single_chunk=True)}"

    def control(self, instance: str) -> str:
        """Key on which the agent sends reconfiguration commands to ``instance``."""
        return f"{self.root}/control/{validate_key_chunks(instance, single_chunk=True)}"

    def status(self, instance: str) -> str:
        """Queryable that answers ``instance``'s counters."""
        return f"{self.root}/status/{validate_key_chunks(instance, single_chunk=True)}"
