"""``ubitrack router`` routes between machines that cannot reach each other otherwise, in real
network namespaces (``tests/integration/netns.py``): a simulated camera on one machine, a
zenoh session (``zenoh_probe``) on another, both clients of routers, no route between them.

Two shapes: one router between two LANs (a machine with a leg on each, forwarding no IP), and
two sites, each with its router, the second router connected to the first over a third LAN
(``deploy/router-site2.yaml``). The probe sees the camera's liveliness token, its fragment
(a query answered across the routers) and its measurements (publications), which match the
scenario's projection; and again after the (first) router is killed and started again.
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from tests.integration.netns import Network
from tests.integration.zenoh_helpers import wait_until
from tests.integration.zenoh_probe import Probe
from ubitrack_agent.core import Position2D, decode
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.sim_trackers.scenario import load_scenario

pytestmark = pytest.mark.integration

PORT = 7447
UBITRACK = (sys.executable, "-m", "ubitrack_agent.cli")
PROBE = (sys.executable, "-m", "tests.integration.zenoh_probe")

TOPOLOGIES = {
    "one router between two LANs": {"lan1": ["camera", "router1"], "lan2": ["probe", "router1"]},
    "two sites, routers linked": {
        "site1": ["camera", "router1"],
        "backbone": ["router1", "router2"],
        "site2": ["probe", "router2"],
    },
}


def unreachable(net: Network, machine: str, address: str) -> str:
    """How a TCP connection from ``machine`` to ``address`` fails (an errno name), "connected"
    if it does not."""
    code = (
        "import errno, socket; s = socket.socket(); s.settimeout(3); "
        f"e = s.connect_ex(({address!r}, {PORT})); print(errno.errorcode.get(e, 'connected'))"
    )
    name = f"reach-{machine}-{address}"
    net.spawn(machine, [sys.executable, "-c", code], name).wait(timeout=10)
    return net.log(name).strip()


@pytest.mark.parametrize("topology", TOPOLOGIES)
def test_clients_of_routers_reach_each_other_only_through_them(netns, topology):
    with netns(TOPOLOGIES[topology]) as net:  # deleted at the end of each shape's test
        check_routing(net, topology)


def check_routing(net: Network, topology: str) -> None:
    router1, router2 = net.machines["router1"], net.machines.get("router2")
    last = router2 or router1
    domain = f"router{net.tag}"
    listen = ("--listen", f"tcp/0.0.0.0:{PORT}")
    net.spawn("router1", [*UBITRACK, "router", *listen], "router1")
    if router2 is not None:  # the second site's router links to the first
        link = f"tcp/{router1.addresses['backbone']}:{PORT}"
        net.spawn("router2", [*UBITRACK, "router", *listen, "--connect", link], "router2")
    lans = list(TOPOLOGIES[topology])
    camera_side = f"tcp/{router1.addresses[lans[0]]}:{PORT}"
    probe_side = f"tcp/{last.addresses[lans[-1]]}:{PORT}"
    member = ("--mode", "client", "--domain", domain)
    net.spawn("camera", [*UBITRACK, "sim", "camera", *member, "--connect", camera_side], "camera")
    keys = KeySpace(f"ubitrack/{domain}")
    logs = lambda: net.logs("router1", "router2", "camera", "probe")  # noqa: E731
    try:  # a client opens once its router answers
        probe = Probe(
            net.spawn("probe", [*PROBE, *member, "--connect", probe_side], "probe", pipes=True)
        )
    except RuntimeError as exc:
        pytest.fail(f"{exc}\n{logs()}")

    assert unreachable(net, "probe", net.machines["camera"].address) == "ENETUNREACH"
    crosses(probe, keys, logs)
    router = net.processes["router1"]  # restarted: every client reconnects, declares again
    os.kill(router.pid, signal.SIGKILL)
    router.wait()
    seen(lambda: not probe.alive(keys.provider("camera")), "the camera's token gone", logs)
    net.spawn("router1", [*UBITRACK, "router", *listen], "router1")
    crosses(probe, keys, logs)
    for name in ("router1", "router2"):
        if name in net.processes:
            assert "ubitrack router: routing on" in net.log(name), logs()


def seen(condition: Callable[[], Any], what: str, logs: Callable[[], str]) -> Any:
    """``condition()`` once truthy, within 30 s; else fail saying what was awaited and seen."""
    try:
        return wait_until(condition, timeout=30)
    except AssertionError:
        pytest.fail(f"not within 30 s: {what}\n{logs()}")


def crosses(probe: Probe, keys: KeySpace, logs: Callable[[], str]) -> None:
    """The probe sees the camera's token, fragment and measurements (true to the scenario)."""
    tokens = seen(lambda: probe.alive(keys.provider("camera")), "the camera's token", logs)
    assert tokens == [keys.provider("camera")], logs()
    # the queryable's declaration may cross the routers after the token's
    fragment = seen(lambda: probe.get_json(keys.fragment("camera")), "its fragment", logs)
    assert {e["name"] for e in fragment["edges"]} >= {"IP_F1", "IP_F5"}, logs()
    world = load_scenario().world
    for _ in range(5):
        payload = probe.next(keys.measured("camera", "IP_F1"))
        assert payload is not None, f"no measurement crossed the router\n{logs()}"
        sample = decode(payload)
        assert isinstance(sample, Position2D)
        truth = world.project("IP", ["F1"], sample.timestamp_ns)["F1"]
        assert np.linalg.norm(sample.position - truth) < 5.0  # pixel noise 0.5 px per axis
