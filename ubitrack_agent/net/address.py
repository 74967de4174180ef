"""Every message names the key it was put on, so that one delivered on another key is refused.

**Why.** Zenoh 1.10 delivered messages on keys they were not put on: in
``tests/integration/test_hosts_netns.py``, within half a second of a machine's links coming
back after a partition longer than zenoh's lease, the subscribers there received other keys'
messages (a command's JSON on a camera's feature key, a worker's ``ErrorPose`` output on a
stored projection's key, samples on a worker's control key, a stop meant for another component,
and the application ``C -> A`` samples two metres off), each with the subscriber's own key,
in 4 of 19 runs (``docs/performance.md``, "Messages that name their key"). The key zenoh
reports is the one the subscriber asked for, so only the message can tell where it was meant
to go. (Presumably a key expression's numeric id resolved against a mapping of the link before
the partition; not reproduced without the host managers' routers, so not reported upstream
yet.)

**What.** Each put and reply of this package carries, as the last :data:`TAG_BYTES` of its
attachment, the CRC-32 of its key (:func:`tag`): the whole attachment of a command or report
(:func:`put_addressed`), after the publisher's id and number on the data path
(``net.sequence``). A reader refuses a message whose attachment is one of ours (a length in
:data:`OURS`) naming another key, counts it
(``misaddressed``) and logs it; a message without an attachment of ours (another program's
publisher, a test's put) is taken as before. CRC-32 (``zlib``, which the standard library
has) is no authentication, only a check against mix-ups: transport security and access
control are zenoh's (``docs/security.md``). O(1) per message after one CRC of the reader's key
(of the message's key for a wildcard subscription).
"""

from __future__ import annotations

import zlib
from typing import Any

import zenoh

TAG_BYTES = 4
"""Bytes of a key's tag: a CRC-32, little-endian."""
NUMBERED_PREFIX_BYTES = 16
"""What comes before the tag in a data path attachment: the publisher's id and the put's
number (``net.sequence``)."""
OURS = (TAG_BYTES, NUMBERED_PREFIX_BYTES + TAG_BYTES)
"""Lengths of this package's attachments, each ending with a key's tag: a command's or
report's (:func:`put_addressed`), a sample's (``net.sequence``)."""


def tag(key: str) -> bytes:
    """The tag naming ``key`` in an attachment."""
    return zlib.crc32(key.encode("utf-8")).to_bytes(TAG_BYTES, "little")


def misaddressed(attachment: bytes | None, key_tag: bytes) -> bool:
    """Whether ``attachment``, one of ours (:data:`OURS`), names another key than the one whose
    tag is ``key_tag``. An attachment of another length is not ours: nothing to tell."""
    return attachment is not None and len(attachment) in OURS and attachment[-TAG_BYTES:] != key_tag


def is_misaddressed(sample: Any, key_tag: bytes | None = None) -> bool:
    """Whether zenoh ``sample`` (a command, report, reply or sample of this package) was meant
    for another key than the one whose tag is ``key_tag`` (by default the key it came on: a
    wildcard subscription's sample, a reply)."""
    found = sample.attachment
    if found is None:
        return False
    return misaddressed(found.to_bytes(), key_tag or tag(str(sample.key_expr)))


def put_addressed(session: Any, key: str, payload: str | bytes, **options: Any) -> None:
    """``session.put`` of ``payload`` on ``key`` with ``options`` (encoding, congestion
    control, priority), its attachment the key's tag."""
    session.put(key, payload, attachment=tag(key), **options)


def reply_addressed(query: Any, key: str, payload: bytes, encoding: zenoh.Encoding) -> None:
    """``query.reply`` with ``payload`` on ``key``, its attachment the key's tag."""
    query.reply(key, payload, encoding=encoding, attachment=tag(key))
