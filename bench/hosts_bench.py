"""Several machines for real (issue 13): network namespaces, one ``ubitrack router``, the
paper's figure-1 simulators split as in a real room (``tests/integration/test_hosts_netns.py``).

Run as root (elsewhere it says why and skips): ``python -m bench.hosts_bench [--trials N]
[--samples N]``. Figures printed and written to ``bench/results/hosts.json``:

* ``reconfiguration``: the machine ``hmd``'s host manager and workers are SIGKILLed (its camera
  and the application stay); from the application seeing the host manager's token vanish to
  its first sample of ``C->A`` after that, computed by the components started again on the
  live hosts (``room``, ``extra``); then ``hmd``'s host manager returns and the pose estimation
  moves back before the next trial.
* ``latency``: the application's ``C->A`` latency (arrival minus the sample's timestamp, ms),
  median and 90th percentile, with the components placed over ``room`` and ``hmd`` (the
  application on ``hmd``) and with everything on ``room`` (sensors, components and the
  application on one machine, still through the router), measured one after the other in one
  run.
* ``clock``: host managers on ``extra`` whose clock is off on purpose (``--clock-offset-ms``):
  their offset estimate (as the agent shows it) against the injected offset, and the
  estimate's own uncertainty (half its best round trip).

Every namespace shares the kernel's clock, so arrival times and timestamps compare directly.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import queue
import signal
import statistics
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from tests.integration.netns import Network, unavailable_reason
from tests.integration.test_hosts_netns import (
    ART_PORT,
    ROUTER_PORT,
    UBITRACK,
    figure1_with_calibration,
)
from tests.integration.zenoh_probe import Probe
from ubitrack_agent.commands.demo import dtrack_flags
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.sim_trackers.scenario import load_scenario

RESULTS = Path(__file__).with_name("results") / "hosts.json"
OFFSETS_MS = (-250.0, 0.0, 400.0)
"""Clock offsets injected into the host managers of ``extra``."""
SETTLE_S = 60.0
"""Longest wait for a flow or a placement to settle."""


@dataclass
class Stack:
    """One deployment: the machines, the probe (the agent's status), the observer's output."""

    net: Network
    probe: Probe
    keys: KeySpace
    flags: Callable[[str], list[str]]
    observer: subprocess.Popen
    lines: queue.SimpleQueue[str] = field(default_factory=queue.SimpleQueue)
    """The observer's output lines, read by a thread of their own."""
    keep: list[int] = field(default_factory=list)
    """Pids on ``hmd`` that are devices, not workers (the camera, the application)."""
    events: list[dict[str, Any]] = field(default_factory=list)

    def read(self, until: Callable[[list[dict[str, Any]]], bool], timeout: float) -> None:
        """Take the observer's lines into :attr:`events` until ``until(events)``."""
        deadline = time.monotonic() + timeout
        while not until(self.events):
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise RuntimeError(f"not within {timeout:.0f} s\n{self.net.logs(lines=15)}")
            with contextlib.suppress(queue.Empty):
                self.events.append(json.loads(self.lines.get(timeout=min(remaining, 0.1))))

    def samples_after(self, t_ns: int) -> list[dict[str, Any]]:
        return [e for e in self.events if "sample" in e and e["arrival"] > t_ns]

    def status(self) -> dict[str, Any]:
        return self.probe.get_json(self.keys.agent_status()) or {}

    def wait_status(self, condition: Callable[[dict[str, Any]], Any], what: str) -> Any:
        deadline = time.monotonic() + SETTLE_S
        while time.monotonic() < deadline:
            if result := condition(self.status()):
                return result
            time.sleep(0.3)
        raise RuntimeError(f"not within {SETTLE_S:.0f} s: {what}\n{self.net.logs(lines=15)}")


def deploy(net: Network, split: bool, scenario_dir: Path) -> Stack:
    """Router, agent and sensors; with ``split`` the camera and the application on ``hmd``
    and a spare host manager on ``extra``, else everything on ``room``."""
    router = f"tcp/{net.machines['router'].address}:{ROUTER_PORT}"
    domain = f"bench{net.tag}"

    def flags(machine: str) -> list[str]:
        return ["--mode", "client", "--connect", router, "--domain", domain, "--host-name", machine]

    def start(machine: str, name: str, *command: str, zenoh: bool = True) -> subprocess.Popen:
        return net.spawn(machine, [*UBITRACK, *command, *(flags(machine) if zenoh else [])], name)

    net.spawn("router", [*UBITRACK, "router", "--listen", f"tcp/0.0.0.0:{ROUTER_PORT}"], "router")
    probe_command = [sys.executable, "-m", "tests.integration.zenoh_probe", *flags("router")]
    probe = Probe(net.spawn("router", probe_command, "probe", pipes=True))
    path = figure1_with_calibration(scenario_dir)
    scenario = load_scenario(path)
    on_scenario = ("--scenario", str(path))
    mobile = "hmd" if split else "room"
    start("room", "agent", "agent", "--no-host", "--quiet")
    start("room", "host-room", "host", "--name", "room", "--pool-size", "2", "--quiet")
    if split:
        for machine in ("hmd", "extra"):
            start(machine, f"host-{machine}", "host", "--name", machine, "--pool-size", "2")
    start("room", "database", "sim", "database", *on_scenario, "--quiet")
    start("room", "art", "sim", "art", "--port", str(ART_PORT), *on_scenario, zenoh=False)
    start("room", "dtrack", "dtrack", *dtrack_flags(scenario.art, ART_PORT), "--quiet")
    camera = start(mobile, "camera", "sim", "camera", *on_scenario, "--quiet")
    observer_command = [sys.executable, "-m", "bench.hosts_observer", "C", "A", "6D"]
    observer = net.spawn(mobile, [*observer_command, *flags(mobile)], "observer", pipes=True)
    stack = Stack(net, probe, KeySpace(f"ubitrack/{domain}"), flags, observer)
    threading.Thread(
        target=lambda: [stack.lines.put(line) for line in observer.stdout], daemon=True
    ).start()
    stack.keep = [camera.pid, observer.pid]
    stack.read(lambda events: len(stack.samples_after(0)) >= 50, timeout=180)
    return stack


def latency_ms(stack: Stack, count: int) -> list[float]:
    """``count`` fresh samples' latencies (ms)."""
    since = time.time_ns()
    stack.read(lambda _: len(stack.samples_after(since)) >= count, timeout=SETTLE_S)
    return [(e["arrival"] - e["sample"]) / 1e6 for e in stack.samples_after(since)[:count]]


def placement(stack: Stack) -> dict[str, str]:
    """Where each component runs, once every one is alive in one process, the one its host
    manager started (not in the middle of a move: else empty)."""
    components = stack.status().get("components", {})
    settled = [
        c["alive"]
        and c["host"]
        and [p.partition(".")[0] for p in c["processes"]] == [str(c["pid"])]
        for c in components.values()
    ]
    if not components or not all(settled):
        return {}
    return {instance: c["host"] for instance, c in components.items()}


def reconfiguration_trial(stack: Stack, initial: dict[str, str]) -> dict[str, float]:
    """Once every component is back where it was placed at first (``initial``: the pose
    estimation, the fusion and the last hop on ``hmd``), kill ``hmd``'s host manager and
    workers; the seconds from its token vanishing (as the application sees it) to the
    application's next sample, and from the kill."""
    stack.wait_status(lambda _: placement(stack) == initial, f"the placement {initial}")
    latency_ms(stack, 30)  # flowing
    killed_at = time.time_ns()
    stack.net.kill_all("hmd", keep=stack.keep)

    def vanished(events: list[dict[str, Any]]) -> bool:
        return any(
            e.get("host") == "hmd" and e["kind"] == "DELETE" and e["at"] > killed_at for e in events
        )

    stack.read(vanished, timeout=SETTLE_S)
    gone = next(
        e["at"]
        for e in stack.events
        if e.get("host") == "hmd" and e["kind"] == "DELETE" and e["at"] > killed_at
    )
    stack.read(lambda _: bool(stack.samples_after(gone)), timeout=SETTLE_S)
    first = stack.samples_after(gone)[0]["arrival"]
    # The machine's host manager returns; the pose estimation moves back for the next trial.
    command = [*UBITRACK, "host", "--name", "hmd", "--pool-size", "2", *stack.flags("hmd")]
    stack.net.spawn("hmd", command, f"host-hmd-{time.monotonic_ns()}")
    return {"from_token_s": (first - gone) / 1e9, "from_kill_s": (first - killed_at) / 1e9}


def clock_trials(stack: Stack) -> list[dict[str, float]]:
    """A host manager on ``extra`` per injected offset: its estimate against the offset."""
    results = []
    for offset_ms in OFFSETS_MS:
        stack.net.kill_all("extra")
        name = f"clock{len(results)}"
        command = [
            *UBITRACK,
            "host",
            "--name",
            name,
            "--pool-size",
            "0",
            "--clock-offset-ms",
            str(offset_ms),
            *stack.flags("extra"),
        ]
        stack.net.spawn("extra", command, f"host-{name}")

        def estimate(status: dict[str, Any], name: str = name) -> dict[str, Any] | None:
            return (status.get("host_info", {}).get(name) or {}).get("clock")

        clock = stack.wait_status(estimate, f"a clock estimate of {name}")
        # The agent's clock minus the host's: the host reads offset_ms ahead.
        error_ms = clock["offset_ns"] / 1e6 + offset_ms
        results.append(
            {
                "injected_ms": offset_ms,
                "estimated_ms": clock["offset_ns"] / 1e6,
                "error_ms": error_ms,
                "uncertainty_ms": clock["uncertainty_ns"] / 1e6,
            }
        )
    return results


def summary(values: list[float]) -> dict[str, float]:
    ordered = sorted(values)
    return {
        "median": statistics.median(ordered),
        "p90": ordered[int(0.9 * (len(ordered) - 1))],
        "min": ordered[0],
        "max": ordered[-1],
        "n": len(ordered),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.hosts_bench", description=__doc__)
    parser.add_argument("--trials", type=int, default=5, help="host failures (default: 5)")
    parser.add_argument("--samples", type=int, default=300, help="samples per latency figure")
    args = parser.parse_args(argv)
    reason = unavailable_reason()
    if reason:
        print(f"hosts_bench: skipped: {reason}", file=sys.stderr)
        return 0
    results: dict[str, Any] = {"machine": platform.node(), "load": os.getloadavg()}
    with Network({"site": ["router", "room", "hmd", "extra"]}) as net:
        stack = deploy(net, split=True, scenario_dir=Path(net.log_dir))
        split_latency = latency_ms(stack, args.samples)
        initial = stack.wait_status(lambda _: placement(stack), "every component placed")
        results["placement"] = initial
        trials = [reconfiguration_trial(stack, initial) for _ in range(args.trials)]
        clocks = clock_trials(stack)
    with Network({"site": ["router", "room"]}) as net:
        stack = deploy(net, split=False, scenario_dir=Path(net.log_dir))
        one_host_latency = latency_ms(stack, args.samples)
    results["latency_ms"] = {
        "split_room_hmd": summary(split_latency),
        "one_host": summary(one_host_latency),
    }
    results["latency_ratio_split_to_one_host"] = (
        results["latency_ms"]["split_room_hmd"]["median"]
        / results["latency_ms"]["one_host"]["median"]
    )
    results["reconfiguration_s"] = {
        "from_token": summary([t["from_token_s"] for t in trials]),
        "from_kill": summary([t["from_kill_s"] for t in trials]),
        "trials": trials,
    }
    results["clock"] = clocks
    print(yaml.safe_dump(results, sort_keys=False))
    RESULTS.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {RESULTS}")
    return 0


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(1))  # Network.close runs on the way out
    sys.exit(main())
