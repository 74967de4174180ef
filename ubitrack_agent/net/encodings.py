"""The encodings the middleware's payloads carry on zenoh, so that generic zenoh tools (and
applications in other languages) know what they hold: ``application/msgpack`` for
measurements (``core.codec``, ``docs/protocol.md`` "Measurements on the wire"), and
``application/json`` for everything else (fragments, statuses, answers, progress, commands,
host requests and reports). Zenoh names no msgpack encoding of its own, so it travels as the
MIME type string."""

from __future__ import annotations

import zenoh

MSGPACK = zenoh.Encoding("application/msgpack")
JSON = zenoh.Encoding.APPLICATION_JSON
