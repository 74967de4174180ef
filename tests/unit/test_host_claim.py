"""One host manager per name (``services/host_claim.py``) on a stand-in session: after the
settle window the first claim serves; a later claim, or any claim while a host token is up,
gives way; malformed claim keys are counted and change nothing."""

from __future__ import annotations

import time
from types import SimpleNamespace

from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.services.host_claim import Claim, HostClaim, first_before, parse_claim

KEYS = KeySpace("ubitrack/test")
PREFIX = f"{KEYS.host('lab')}/claim/"


class FakeSession:
    def __init__(self) -> None:
        self.tokens: list[str] = []
        self.callbacks: dict[str, object] = {}
        self.undeclared: list[str] = []

    def liveliness(self):
        return SimpleNamespace(declare_token=self._token, declare_subscriber=self._subscribe)

    def _token(self, key):
        self.tokens.append(key)
        return SimpleNamespace(undeclare=lambda: None)

    def _subscribe(self, key, callback, history=False):
        assert key in (f"{PREFIX}*", KEYS.host("lab")) and history
        self.callbacks[key] = callback
        return SimpleNamespace(undeclare=lambda: self.undeclared.append(key))

    def claim(self, kind: str, key: str) -> None:
        self.callbacks[f"{PREFIX}*"](SimpleNamespace(kind=f"SampleKind.{kind}", key_expr=key))

    def host(self, kind: str) -> None:
        host = KEYS.host("lab")
        self.callbacks[host](SimpleNamespace(kind=f"SampleKind.{kind}", key_expr=host))


def test_claim_keys_parse_totally():
    assert parse_claim(f"{PREFIX}1700000000000000000.77.4242", PREFIX) == Claim(
        1700000000000000000, 77, 4242
    )
    bad = ("x.1.2", "1.2", "1..2", ".1.2", "1.2.3.4", "1", "-1.2.3", "9" * 30 + ".1.2", "1.2.x")
    for key in bad:
        assert parse_claim(PREFIX + key, PREFIX) is None, key
    assert parse_claim("ubitrack/other/claim/1.2.3", PREFIX) is None


def test_the_first_claim_by_start_then_nonce_serves_unless_a_host_token_is_up():
    own = Claim(100, 50, 1)
    assert first_before(own, [own, Claim(100, 51, 2), Claim(200, 0, 3)], served=False) is None
    assert "pid 2" in first_before(own, [own, Claim(100, 49, 2)], served=False)
    assert "pid 3" in first_before(own, [Claim(100, 49, 2), Claim(99, 99, 3)], served=False)
    assert "serves already" in first_before(own, [own], served=True)


def test_a_claim_decides_once_its_window_has_passed_on_what_it_heard():
    session = FakeSession()
    claim = HostClaim(session, KEYS, "lab", settle_s=0.3)
    own = claim.own
    assert session.tokens == [PREFIX + own.chunk()]
    session.claim("PUT", PREFIX + own.chunk())  # its own
    session.claim("PUT", f"{PREFIX}{own.start_ns + 5}.1.9")  # a later one
    session.claim("PUT", f"{PREFIX}not-a-claim")
    assert claim.counters["rejected_claim_keys"] == 1
    session.claim("PUT", f"{PREFIX}{own.start_ns - 5}.1.8")  # an earlier one...
    session.claim("DELETE", f"{PREFIX}{own.start_ns - 5}.1.8")  # ...gone before the decision
    began = time.monotonic()
    assert claim.settle() is None  # it serves
    assert time.monotonic() - began > 0.2  # it waited out its window
    assert sorted(session.undeclared) == sorted(session.callbacks)  # stops watching

    other = FakeSession()
    loser = HostClaim(other, KEYS, "lab", settle_s=0.0)
    other.claim("PUT", PREFIX + Claim(loser.own.start_ns - 1, 0, 4242).chunk())
    assert "pid 4242" in loser.settle()

    late = FakeSession()
    latecomer = HostClaim(late, KEYS, "lab", settle_s=0.0)
    host = KEYS.host("lab")
    wildcard = SimpleNamespace(kind="SampleKind.PUT", key_expr=f"{KEYS.root}/host/*")
    hostile = FakeSession()
    unmoved = HostClaim(hostile, KEYS, "lab", settle_s=0.0)
    hostile.callbacks[host](wildcard)  # a hostile token matching every host: no host manager's
    assert unmoved.counters["rejected_host_tokens"] == 1
    assert unmoved.settle() is None
    late.host("PUT")  # one serves (its claim may even look later, across clocks)
    assert "serves already" in latecomer.settle()
