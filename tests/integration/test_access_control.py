"""The opt-in secure setup (docs/security.md) with real processes: the agent is a zenoh router
on mutual TLS enforcing the access control that ``ubitrack certs`` writes; a tracker and an
application are clients with their own certificates. The legitimate flow works; what an
unknown certificate, a provider's or an application's certificate writes where its role may
not (poses, control commands, tokens) is dropped by the router, and the application's values
stay correct; an application's subscriber on a component's output key (the flow's wiring,
net.access) receives nothing; without a certificate, or with one from another CA, nothing
connects."""

from __future__ import annotations

import argparse
import contextlib
import json
import queue
import shutil
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from tests.integration.zenoh_helpers import Collector, free_port, wait_until
from ubitrack_agent.commands import certs
from ubitrack_agent.core import ErrorPose, MeasurementError, se3
from ubitrack_agent.core.codec import decode, encode
from ubitrack_agent.io.application import Relation
from ubitrack_agent.net import config
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.session import open_session
from ubitrack_agent.net.transport import fetch_latest
from ubitrack_agent.sim_trackers.exact_tracker import true_wt_ht

pytestmark = [
    pytest.mark.integration,
    pytest.mark.skipif(
        shutil.which("openssl") is None, reason="needs the openssl command to make certificates"
    ),
]

WT_HT = RelationId("WT", "HT", "6D")
FAR = ErrorPose(0, np.array([0.0, 0.0, 1.0, 0.0]), np.array([3.0, 3.0, 3.0]), np.eye(6) * 1e-6)
"""A well-formed pose 180 degrees and metres off, what an attacker would inject."""
STOP = b'{"stop":true}'
"""A stop command spelt unlike the agent's and host managers' (``{"stop": true}``)."""


@dataclass
class Secure:
    directory: Path
    port: int
    keys: KeySpace
    processes: list

    def settings(self, name: str, certificate: str | None = None) -> config.Settings:
        """The settings ``ubitrack certs`` wrote for ``name``, optionally with another
        certificate (``<certificate>.pem`` in the same directory)."""
        flags = {"connect": [f"tls/localhost:{self.port}"]}
        if certificate is not None:
            flags["tls_certificate"] = str(self.directory / f"{certificate}.pem")
            flags["tls_key"] = str(self.directory / f"{certificate}-key.pem")
        return config.resolve("member", self.directory / f"{name}.yaml", env={}, flags=flags)

    def start(self, *command: str, name: str) -> subprocess.Popen:
        settings = self.directory / f"{name}.yaml"
        process = subprocess.Popen(
            [sys.executable, *command, "--config", str(settings)], start_new_session=True
        )
        self.processes.append(process)
        return process


def _certificates(directory: Path, port: int, domain: str) -> None:
    """The setup's certificates, plus ``intruder`` (our CA, no role) and ``forged/ART``
    (the ART provider's name, from another CA)."""
    certs.generate(
        argparse.Namespace(
            directory=directory,
            provider=["ART", "camera"],
            hub_host=[],
            hub_port=port,
            prefix="ubitrack",
            domain=domain,
            days=1,
        )
    )
    certs.issue(directory, "intruder", 1)
    forged = directory / "forged"
    forged.mkdir()
    certs.make_ca(forged, 1)
    certs.issue(forged, "ART", 1)
    shutil.copy(forged / "ART.pem", directory / "forged-ART.pem")
    shutil.copy(forged / "ART-key.pem", directory / "forged-ART-key.pem")


@pytest.fixture
def secure(tmp_path, processes) -> Iterator[Secure]:
    port = free_port()
    domain = f"tls{port}"
    _certificates(tmp_path, port, domain)
    setup = Secure(tmp_path, port, KeySpace(f"ubitrack/{domain}"), processes)
    setup.start(
        *("-m", "ubitrack_agent.cli", "agent", "--pool-size", "1"),
        *("--listen", f"tls/127.0.0.1:{port}"),
        name="agent",
    )
    yield setup


def _status(session, keys: KeySpace) -> dict | None:
    replies = fetch_latest(session, keys.agent_status(), timeout=0.5)
    return json.loads(replies[0]) if replies else None


def _assert_true(samples: list) -> None:
    for sample in samples:
        q, t = true_wt_ht(sample.timestamp_ns)
        np.testing.assert_allclose(
            se3.to_matrix(sample.rotation, sample.translation), se3.to_matrix(q, t), atol=3e-3
        )


def _attack(session, keys: KeySpace, instances: list[str], name: str) -> list:
    """Inject poses, relations and stop commands, declare tokens; the tokens (to keep)."""
    for _ in range(50):
        pose = encode(ErrorPose(time.time_ns(), FAR.rotation, FAR.translation, FAR.covariance))
        session.put(keys.measured("ART", "HT"), pose)
        session.put(keys.relation(WT_HT), pose)
        for instance in instances:
            session.put(keys.data(f"{instance}/out"), pose)
            session.put(keys.control(instance), STOP)
        time.sleep(0.01)
    liveliness = session.liveliness()
    return [
        liveliness.declare_token(keys.worker(f"fake-{name}", "1.fake")),
        liveliness.declare_token(keys.provider(f"fake-{name}")),
        liveliness.declare_token(keys.pool(f"fake-{name}")),
    ]


def _injected_pose(payload: bytes) -> bool:
    """Whether ``payload`` is one of the attacker's poses (its translation, to the bit): not a
    search for the bytes of 3.0, which a legitimate covariance's can hold by chance."""
    try:
        value = decode(payload)
    except MeasurementError:
        return False  # a progress or answer message, or a status
    return isinstance(value, ErrorPose) and np.array_equal(value.translation, FAR.translation)


def _tokens(session, selector: str) -> set[str]:
    return {str(reply.ok.key_expr) for reply in session.liveliness().get(selector, timeout=1.0)}


@contextlib.contextmanager
def _flowing(secure: Secure) -> Iterator[tuple[Any, Any, Relation]]:
    """The agent's flow from the tracker ``ART`` to an application's relation ``WT_HT``,
    flowing: a session with the host's certificate (it may subscribe to everything,
    components' outputs too), the application's session and its relation."""
    keys = secure.keys
    with open_session(secure.settings("operator", "host")) as observer:
        wait_until(lambda: _status(observer, keys) is not None, timeout=30)
        secure.start("-m", "ubitrack_agent.sim_trackers.exact_tracker", "--provider", "ART",
                     "--tracker", "ART", "--yaw", "30", "--x", "2", name="ART")  # fmt: skip
        with (
            open_session(secure.settings("application")) as app_session,
            Relation(app_session, keys, WT_HT, application="app") as relation,
        ):
            wait_until(relation.latest, timeout=40)
            yield observer, app_session, relation


def test_only_authorised_certificates_write_and_the_application_stays_correct(secure):
    keys = secure.keys
    with _flowing(secure) as (observer, _, relation):
        _assert_true([relation.get(timeout=5) for _ in range(20)])
        status = _status(observer, keys)
        instances = [i for i, c in status["components"].items() if c["alive"]]
        pids = {i: json.loads(fetch_latest(observer, keys.status(i))[0])["pid"] for i in instances}
        injected = Collector(observer, keys.pattern("**"))

        tokens = []
        for name, certificate in (
            ("application", "intruder"),  # our CA, no role
            ("camera", None),  # another provider
            ("application", None),  # an application
        ):
            with open_session(secure.settings(name, certificate)) as attacker:
                time.sleep(0.3)  # its link is up
                tokens += _attack(attacker, keys, instances, certificate or name)
                _assert_true([relation.get(timeout=5) for _ in range(20)])
        time.sleep(0.5)

        received = []
        while not injected.items.empty():
            received.append(injected.items.get_nowait())
        assert STOP not in received
        assert not [r for r in received if _injected_pose(r)]
        assert not _tokens(observer, keys.pattern("*", "fake-$*"))
        status = _status(observer, keys)
        assert not [p for p in status["providers"] if p.startswith("fake-")]
        for instance, pid in pids.items():  # nobody stopped them
            assert json.loads(fetch_latest(observer, keys.status(instance))[0])["pid"] == pid
            assert status["components"][instance]["alive"]
        _assert_true([relation.get(timeout=5) for _ in range(20)])
        assert relation.rejected == 0


def test_only_agent_and_host_certificates_read_a_component_output(secure):
    """A component's output is the data flow's wiring, read by components alone (net.access):
    an application's subscriber on it is refused (it receives nothing), while the host's
    certificate receives it and the relation keeps flowing to the application."""
    keys = secure.keys
    with _flowing(secure) as (host_reader, app_session, relation):
        instances = {i for i, c in _status(host_reader, keys)["components"].items() if c["alive"]}
        seen: queue.SimpleQueue[str] = queue.SimpleQueue()
        outputs = host_reader.declare_subscriber(
            keys.pattern("data", "*", "*"), lambda s: seen.put(str(s.key_expr))
        )
        counts: Counter[str] = Counter()
        while not counts or max(counts.values()) < 3:  # a running component's dynamic output
            key = seen.get(timeout=10)
            if key.split("/")[-2] in instances:
                counts[key] += 1
        output = max(counts, key=counts.__getitem__)
        host_sees = Collector(host_reader, output)
        app_sees = Collector(app_session, output)
        app_keys: queue.SimpleQueue[str] = queue.SimpleQueue()
        app_sees_all = app_session.declare_subscriber(
            keys.pattern("data", "**"), lambda s: app_keys.put(str(s.key_expr))
        )
        provider = Collector(app_session, keys.measured("ART", "HT"))
        time.sleep(0.5)  # the declarations reached the router
        host_sees.drain()
        _assert_true([relation.get(timeout=5) for _ in range(20)])
        assert host_sees.next(timeout=5)  # the output flows, and the host reads it
        assert provider.next(timeout=5)  # a provider's data stays readable
        assert app_sees.items.empty()
        # what reaches the application's session (the provider's data, for the subscriber
        # above) is handed to its local wildcard subscriber too; no component output is
        received = set()
        while not app_keys.empty():
            received.add(app_keys.get_nowait())
        assert not [k for k in received if k.split("/")[-2] in instances]
        outputs.undeclare()
        app_sees_all.undeclare()


@pytest.mark.parametrize("certificate", ["none", "forged-ART"])
def test_no_certificate_or_another_ca_cannot_connect(secure, certificate):
    keys = secure.keys
    with open_session(secure.settings("operator")) as observer:
        wait_until(lambda: _status(observer, keys) is not None, timeout=30)
    options = secure.settings("ART", None if certificate == "none" else certificate).zenoh_options()
    if certificate == "none":  # TLS trusting the CA, but no client certificate
        ca = options["transport/link/tls"]["root_ca_certificate"]
        options["transport/link/tls"] = {"root_ca_certificate": ca}
    options["connect/timeout_ms"] = 3000  # the hub answers a legitimate client in milliseconds
    zenoh_config = zenoh.Config()
    for path, value in options.items():
        zenoh_config.insert_json5(path, json.dumps(value))
    with pytest.raises(zenoh.ZError):
        zenoh.open(zenoh_config)
