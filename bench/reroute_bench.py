"""How long a container's worker token is gone when its host manager, its zenoh gateway, is
SIGKILLed (issue 28, "Fewer links"; ``docs/services.md``, "Links").

Run: ``python -m bench.reroute_bench [--trials 5]``. Real processes on loopback with real
zenoh: this process is the hub; per trial a host manager (``python -m
ubitrack_agent.services.host``, its worker processes its zenoh clients, the default) starts one
container with a relay, then is SIGKILLed; the container, which outlives it, reaches the network
through the hub (the next endpoint in its connect list) and declares its token again. The figure per
trial is the time from the token's removal to its return, as the hub's liveliness subscriber sees
them: what the agent's ``REROUTE_S`` must cover before it starts such a component again. Printed and
written to ``bench/results/reroute.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from tests.integration.conftest import kill_tagged
from tests.integration.zenoh_helpers import free_port, member_flags, wait_until
from ubitrack_agent.net import config
from ubitrack_agent.net.host_protocol import Request, StartGroup, Status, encode_request
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.net.session import open_session
from ubitrack_agent.net.spec import ComponentSpec, GroupSpec, InputBinding

RESULTS = Path(__file__).with_name("results") / "reroute.json"


def trial(session: Any, keys: KeySpace, port: int, domain: str, index: int) -> float:
    """One host manager with one container, SIGKILLed: seconds its token was gone."""
    events: list[tuple[str, float]] = []
    watch = session.liveliness().declare_subscriber(
        keys.all_workers(), lambda s: events.append((str(s.kind), time.monotonic()))
    )
    flags = member_flags(port, domain)
    command = [
        sys.executable,
        "-m",
        "ubitrack_agent.services.host",
        "--name",
        "lab",
        "--pool-size",
        "1",
    ]
    host = subprocess.Popen([*command, "--quiet", *flags], start_new_session=True)

    def granted(request: Request) -> bool:
        replies = list(
            session.get(keys.host_request("lab"), payload=encode_request(request), timeout=2.0)
        )
        return bool(replies) and replies[0].ok is not None

    wait_until(lambda: granted(Status()), timeout=60)
    instance = f"relay{index}"
    spec = ComponentSpec(
        instance,
        "relay",
        (InputBinding("in", keys.data("src/in"), trigger=True),),
        {"out": keys.data(f"{instance}/out")},
    )
    assert granted(StartGroup(GroupSpec("lab-0", (spec,))))
    wait_until(lambda: any(kind.endswith("PUT") for kind, _ in events), timeout=60)
    time.sleep(1.0)  # steady
    events.clear()
    host.kill()
    host.wait()
    wait_until(lambda: any(kind.endswith("PUT") for kind, _ in events), timeout=20)
    watch.undeclare()
    removed = [t for kind, t in events if kind.endswith("DELETE")]
    returned = [t for kind, t in events if kind.endswith("PUT")]
    return returned[0] - removed[0] if removed else 0.0


def main() -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.reroute_bench", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--trials", type=int, default=5)
    args = parser.parse_args()
    port = free_port()
    domain = f"reroute{port}"
    settings = config.Settings(listen=(f"tcp/127.0.0.1:{port}",), domain=domain)
    keys = KeySpace(settings.key_prefix)
    load = os.getloadavg()
    try:
        with open_session(settings) as session:
            gone = [trial(session, keys, port, domain, index) for index in range(args.trials)]
    finally:
        kill_tagged(domain)  # the containers that outlived their host managers
    result = {
        "command": "python -m bench.reroute_bench",
        "date": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
        "machine": f"{platform.machine()}, {os.cpu_count()} CPUs, {platform.python_version()}",
        "load_average": [round(x, 2) for x in (*load, *os.getloadavg())],
        "token_gone_s": [round(seconds, 4) for seconds in gone],
        "token_gone_median_s": round(statistics.median(gone), 4),
        "token_gone_max_s": round(max(gone), 4),
    }
    print(json.dumps(result, indent=1))
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
