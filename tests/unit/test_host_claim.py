"""One host manager per name (``services/host_claim.py``) on a stand-in session: the earliest
claim serves, a later one waits until the earlier ones are gone; malformed claim keys are
counted and change nothing."""

from __future__ import annotations

import threading
from types import SimpleNamespace

from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.services.host_claim import HostClaim, parse_claim

KEYS = KeySpace("ubitrack/test")
PREFIX = f"{KEYS.host('lab')}/claim/"


class FakeSession:
    def __init__(self) -> None:
        self.tokens: list[str] = []
        self.callback = None

    def liveliness(self):
        return SimpleNamespace(declare_token=self._token, declare_subscriber=self._subscribe)

    def _token(self, key):
        self.tokens.append(key)
        return SimpleNamespace(undeclare=lambda: None)

    def _subscribe(self, key, callback, history=False):
        assert key == f"{PREFIX}*" and history
        self.callback = callback
        return SimpleNamespace(undeclare=lambda: None)

    def claim(self, kind: str, key: str) -> None:
        self.callback(SimpleNamespace(kind=f"SampleKind.{kind}", key_expr=key))


def test_claim_keys_parse_totally():
    assert parse_claim(f"{PREFIX}1700000000000000000.4242", PREFIX) == (1700000000000000000, 4242)
    for bad in ("x.1", "1.", ".1", "1.2.3", "1", "-1.2", "9" * 30 + ".1", "1.x"):
        assert parse_claim(PREFIX + bad, PREFIX) is None, bad
    assert parse_claim("ubitrack/other/claim/1.2", PREFIX) is None


def test_a_later_host_manager_waits_for_the_earlier_one():
    session = FakeSession()
    claim = HostClaim(session, KEYS, "lab")
    start, pid = claim.own
    assert session.tokens == [f"{PREFIX}{start}.{pid}"]
    session.claim("PUT", f"{PREFIX}{start}.{pid}")  # its own: no wait
    session.claim("PUT", f"{PREFIX}{start + 5}.1")  # a later one: it waits for this one
    session.claim("PUT", f"{PREFIX}not-a-claim")
    assert claim.counters["rejected_claim_keys"] == 1
    session.claim("PUT", f"{PREFIX}{start - 5}.1")  # an earlier one serves
    waited = threading.Thread(target=claim.wait_until_first)
    waited.start()
    waited.join(timeout=0.3)
    assert waited.is_alive()  # held back
    session.claim("DELETE", f"{PREFIX}{start - 5}.1")  # gone
    waited.join(timeout=5)
    assert not waited.is_alive()
