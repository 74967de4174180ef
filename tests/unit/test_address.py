"""Messages name the key they were put on (``net.address``)."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from ubitrack_agent.net.address import OURS, TAG_BYTES, misaddressed, tag
from ubitrack_agent.net.sequence import ATTACHMENT_BYTES, Numbering

KEYS = st.text(alphabet="abcdefghijklmnopqrstuvwxyz0123456789-_/", min_size=1, max_size=80)


@given(KEYS, KEYS)
def test_a_tag_tells_two_keys_apart_and_names_its_own(one, other):
    assert len(tag(one)) == TAG_BYTES
    assert not misaddressed(tag(one), tag(one))
    if one != other and tag(one) != tag(other):  # CRC-32 collides once in 2**32 pairs
        assert misaddressed(tag(one), tag(other))
        assert misaddressed(Numbering(one).next(), tag(other))


@given(st.one_of(st.none(), st.binary(max_size=64)))
def test_an_attachment_not_of_ours_is_never_refused(found):
    """Another program's publisher (any attachment of another length, or none) is taken as
    before: only an attachment of ours can name a key."""
    if found is None or len(found) not in OURS:
        assert not misaddressed(found, tag("a/b"))


def test_a_numbered_attachment_ends_with_its_key_tag():
    attachment = Numbering("a/b").next()
    assert len(attachment) == ATTACHMENT_BYTES and ATTACHMENT_BYTES in OURS
    assert attachment[-TAG_BYTES:] == tag("a/b")
