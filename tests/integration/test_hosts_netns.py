"""The paper's figure-1 setup distributed over machines for real: each machine a network
namespace (``tests/integration/netns.py``) on one LAN, every process a zenoh client of a
``ubitrack router`` (``docs/operations.md``, "Several machines").

* ``router``: ``ubitrack router``, and the test's eyes (``zenoh_probe``: the agent's status).
* ``room``: the agent (``--no-host``: every machine runs its own ``ubitrack host``, as with the
  systemd units, so a machine's workers can fail without the agent), ``ubitrack host --name
  room``, the calibration database (the scenario's static edges, ``C->HT`` included, so that
  nothing is calibrated first), the simulated A.R.T. tracker and its DTrack adapter.
* ``hmd``, whose clock reads 200 ms ahead (``--clock-offset-ms``; its host manager measures
  that, and the agent aligns the camera's timestamps with the A.R.T.'s where they meet):
  ``ubitrack host --name hmd``, the simulated camera, and the application,
  ``ubitrack subscribe C A --type 6D``, whose samples the test compares with the scenario's
  ground truth at their timestamps (the demo's bound: 30 mm RMS).
* ``extra``: empty until a host manager joins later.

The tests share that deployment and run in order (if the relation never flows, the others
are skipped):

1. the relation flows and is true;
2. placement: the 2D-3D pose estimation runs on ``hmd``, beside the camera whose features it
   reads (and the fusion beside the application, the A.R.T. chain in the room);
3. the host manager of ``hmd`` alone is SIGKILLed: its workers keep running (same pids), and
   the flow with them; it is started again;
4. ``hmd``'s workers fail: its host managers and every worker there are SIGKILLed, the camera
   (a device of its own) stays; the components run on a live host, the flow returns;
5. the machine ``hmd`` fails: every process there but the application (the test's observer),
   the camera included; the A.R.T. path runs on a live host and flows; the machine returns
   (camera, host manager) and the pose estimation with it;
6. ``hmd``'s cable is pulled for a few seconds (less than zenoh's lease) and plugged back;
7. a partition longer than the lease: the router drops ``hmd``'s clients, which reconnect;
8. a host manager joins on ``extra``, is seen by the agent, and is given every component once
   the other machines' workers fail.

Every failure message shows what was seen: the agent's status and the tails of the logs.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from tests.integration.netns import Network
from tests.integration.zenoh_probe import Probe
from ubitrack_agent.commands.demo import dtrack_flags
from ubitrack_agent.core import quaternions
from ubitrack_agent.net.keys import KeySpace
from ubitrack_agent.sim_trackers.scenario import DEFAULT_SCENARIO, Scenario, load_scenario

pytestmark = pytest.mark.integration

ROUTER_PORT = 7447
ART_PORT = 5000  # in room's own namespace: no other run can hold it
UBITRACK = (sys.executable, "-m", "ubitrack_agent.cli", "--log-level", "INFO")
POSE_ESTIMATION = "pose_estimation_2d3d"
"""The service of the 2D-3D pose estimation (templates/pose_estimation_2d3d.yaml)."""
ERROR_BOUND_MM = 30.0
"""The demo test's bound on a phase's RMS position error (a few mm expected)."""
ERROR_BOUND_DEG = 2.0
"""A bound as gross on the RMS rotation error (a tenth of a degree or so expected)."""
SAMPLES = 30
"""Samples judged after each event (the camera-only flow runs at 30 Hz)."""
FIRST_FLOW_S = 120.0
"""Longest wait for the first sample: every process starts cold on a shared machine."""
RECOVERY_S = 60.0
"""Longest wait for the flow to return after an event."""
HMD_CLOCK_AHEAD_MS = 200.0
"""The HMD computer's clock reads this much ahead of the room's (the agent's): its camera
stamps features on it, so the fusion of its pose with the A.R.T.'s must be aligned."""
CUT_S = 4.0
"""How long hmd's cable stays out: shorter than zenoh's lease (10 s), so links survive."""


@dataclass
class Deployment:
    net: Network
    probe: Probe
    keys: KeySpace
    world: Any
    flags: Callable[[str], list[str]]
    app_log: Path
    offset: int = 0
    partial: bytes = b""
    scenario_flags: tuple[str, ...] = ()
    """``--scenario FILE``: the simulators' scenario."""
    never_flowed: bool = False
    """The first test saw no flow: the others, which start from one, are skipped."""
    others: dict[str, int] = field(default_factory=dict)
    """Pid of each process that is not a host manager or a worker (the agent, sensors, the
    application), by name."""

    # -- processes --------------------------------------------------------------------------

    def start(self, machine: str, name: str, *command: str, zenoh: bool = True) -> subprocess.Popen:
        """A ``ubitrack`` command on ``machine``, a client of the router (if ``zenoh``)."""
        flags = self.flags(machine) if zenoh else []
        return self.net.spawn(machine, [*UBITRACK, *command, *flags], name)

    def start_host(self, machine: str) -> subprocess.Popen:
        """The host manager of ``machine``, named after it (a small warm pool)."""
        host = f"host-{machine}"
        if host in self.net.processes:  # started again: a log of its own
            host = f"{host}-{len(self.net.processes)}"
        return self.start(machine, host, "host", "--name", machine, "--pool-size", "2")

    def other(self, machine: str, name: str, *command: str, zenoh: bool = True) -> None:
        """A process that runs no workers (:attr:`others`)."""
        self.others[name] = self.start(machine, name, *command, zenoh=zenoh).pid

    def fail_workers(self, machine: str) -> set[int]:
        """Kill every process on ``machine`` but :attr:`others`: its host managers and all
        its workers. The killed pids."""
        return self.net.kill_all(machine, keep=list(self.others.values()))

    # -- what is seen -----------------------------------------------------------------------

    def status(self) -> dict | None:
        return self.probe.get_json(self.keys.agent_status())

    def summary(self) -> str:
        """The agent's status in short: hosts and where each component runs."""
        try:
            status = self.status()
        except RuntimeError as exc:  # the probe itself failed
            return f"agent status: unknown ({exc})"
        if status is None:
            return "agent status: no answer"
        components = {
            instance: f"{c['service']} on {c['host']} ({'alive' if c['alive'] else 'not alive'})"
            for instance, c in status["components"].items()
        }
        seen = {
            "hosts": status["hosts"],
            "components": components,
            "unsolved": status["unsolved"],
            "problems": status.get("problems"),
        }
        return "agent status: " + json.dumps(seen, indent=1)

    def explain(self) -> str:
        """What was seen: the status, the tails of the logs, the application's last lines."""
        logs = [name for name in self.net.processes if name != "application"]
        return "\n".join(
            (self.summary(), self.net.logs(*logs, lines=20), self.net.logs("application", lines=2))
        )

    def new_samples(self) -> list[dict]:
        """The application's samples printed since the last call."""
        with self.app_log.open("rb") as log:
            log.seek(self.offset)
            data = log.read()
        self.offset += len(data)
        *lines, self.partial = (self.partial + data).split(b"\n")
        return [json.loads(line) for line in lines if line.startswith(b"{")]

    def fresh_samples(self, timeout: float, count: int = SAMPLES) -> list[dict]:
        """``count`` samples measured after this call (older ones are skipped)."""
        since = time.time_ns()
        self.new_samples()
        fresh: list[dict] = []
        deadline = time.monotonic() + timeout
        while len(fresh) < count:
            if time.monotonic() > deadline:
                raise AssertionError(
                    f"{len(fresh)} of {count} fresh C->A samples within {timeout:.0f} s\n"
                    + self.explain()
                )
            fresh += [s for s in self.new_samples() if s["timestamp_ns"] > since]
            time.sleep(0.1)
        return fresh

    def assert_true(self, samples: list[dict]) -> None:
        """The samples' RMS errors against the ground truth are within the demo's bounds."""
        mm, deg = [], []
        for sample in samples:
            q, t = self.world.pose("C", "A", sample["timestamp_ns"])
            mm.append(np.linalg.norm(np.asarray(sample["translation"]) - t) * 1000)
            relative = quaternions.multiply(
                quaternions.conjugate(q), np.asarray(sample["rotation"])
            )
            deg.append(np.degrees(quaternions.angle(relative)))
        rms_mm, rms_deg = (float(np.sqrt(np.mean(np.square(e)))) for e in (mm, deg))
        assert rms_mm < ERROR_BOUND_MM and rms_deg < ERROR_BOUND_DEG, (
            f"C->A error {rms_mm:.1f} mm, {rms_deg:.2f} deg RMS\n{self.explain()}"
        )

    def worker_pids(self, instances: set[str]) -> dict[str, int]:
        """Each instance's worker pid, once every one has answered its status query (one may
        time out on a loaded machine: a missing pid is no evidence)."""

        def pids(_: dict) -> dict[str, int] | None:
            replies = {i: self.probe.get_json(self.keys.status(i)) for i in instances}
            known = {i: reply["pid"] for i, reply in replies.items() if reply}
            return known if len(known) == len(instances) else None

        return self.wait_for(pids, RECOVERY_S, f"the pids of {sorted(instances)}")

    def wait_for(self, condition: Callable[[dict], Any], timeout: float, what: str) -> Any:
        """Poll the agent's status until ``condition(status)`` is truthy; fail saying
        ``what`` was awaited and what was seen."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            status = self.status()
            if status is not None and (result := condition(status)):
                return result
            time.sleep(0.3)
        raise AssertionError(f"not within {timeout:.0f} s: {what}\n{self.explain()}")


def figure1_with_calibration(directory: Path) -> Path:
    """The default scenario with ``C->HT`` in the database, so tracking starts at once."""
    scenario = yaml.safe_load(DEFAULT_SCENARIO.read_text())
    scenario["database"]["edges"].append({"from": "C", "to": "HT", "type": "6D"})
    path = directory / "figure1_calibrated.yaml"
    path.write_text(yaml.safe_dump(scenario))
    return path


@pytest.fixture(scope="module")
def deployment(netns, tmp_path_factory) -> Iterator[Deployment]:
    net = netns({"site": ["router", "room", "hmd", "extra"]})
    router = f"tcp/{net.machines['router'].address}:{ROUTER_PORT}"
    domain = f"hosts{net.tag}"

    def flags(machine: str) -> list[str]:
        clock = ["--clock-offset-ms", str(HMD_CLOCK_AHEAD_MS)] if machine == "hmd" else []
        return [
            *("--mode", "client", "--connect", router, "--domain", domain),
            *("--host-name", machine, *clock),
        ]

    net.spawn("router", [*UBITRACK, "router", "--listen", f"tcp/0.0.0.0:{ROUTER_PORT}"], "router")
    probe_command = [sys.executable, "-m", "tests.integration.zenoh_probe", *flags("router")]
    try:
        probe = Probe(net.spawn("router", probe_command, "probe", pipes=True))
    except RuntimeError as exc:
        pytest.fail(f"{exc}\n{net.logs()}")
    path = figure1_with_calibration(tmp_path_factory.mktemp("scenario"))
    scenario: Scenario = load_scenario(path)
    d = Deployment(
        net,
        probe,
        KeySpace(f"ubitrack/{domain}"),
        scenario.world,
        flags,
        net.log_dir / "application.log",
    )
    d.other("room", "agent", "agent", "--no-host")
    d.start_host("room")
    d.start_host("hmd")
    d.wait_for(lambda s: s["hosts"] == ["hmd", "room"], 60, "host managers room and hmd seen")
    on_scenario = d.scenario_flags = ("--scenario", str(path))
    d.other("room", "database", "sim", "database", *on_scenario)
    d.other("room", "art", "sim", "art", "--port", str(ART_PORT), *on_scenario, zenoh=False)
    d.other("room", "dtrack", "dtrack", *dtrack_flags(scenario.art, ART_PORT))
    d.other("hmd", "camera", "sim", "camera", *on_scenario)
    d.other(
        "hmd", "application", "subscribe", "C", "A", "--type", "6D", "--wait", "--timeout", "inf"
    )
    yield d


def placed(status: dict) -> dict[str, str | None]:
    """Where each wanted component runs, once every one is alive and placed; else empty."""
    components = status["components"]
    every = components and all(c["alive"] and c["host"] for c in components.values())
    return {i: c["host"] for i, c in components.items()} if every else {}


@pytest.fixture
def live(deployment) -> Deployment:
    """The deployment, once its relation has flowed (else the test is skipped: it would only
    wait for its own time-outs; the first test's failure says why)."""
    if deployment.never_flowed:
        pytest.skip("C->A never flowed: see the failure of the first test")
    return deployment


def test_the_relation_flows_across_machines_and_is_true(deployment):
    """The relation flows; once hmd's clock is measured, the agent has aligned the camera's
    stream with the A.R.T.'s (until then the fusion mixes times 200 ms apart, and the agent
    says so in its status) and every component of the flow runs, it is true."""
    try:
        deployment.fresh_samples(FIRST_FLOW_S)
    except AssertionError:
        deployment.never_flowed = True
        raise
    deployment.wait_for(
        lambda s: (
            not s["clock_problems"]
            and s["host_info"].get("hmd", {}).get("clock")
            and all(c["alive"] for c in s["components"].values())
        ),
        RECOVERY_S,
        "hmd's clock measured, no clock problem and every component alive",
    )
    deployment.assert_true(deployment.fresh_samples(RECOVERY_S))


def hosts_of(status: dict, service: str) -> set[str]:
    """Where the components of ``service`` run, once every component is alive and placed."""
    where = placed(status)
    components = status["components"].items()
    return {where[i] for i, c in components if where and c["service"] == service}


def pose_estimation_hosts(status: dict) -> set[str]:
    """Where the pose estimation runs, once every component is alive and placed."""
    return hosts_of(status, POSE_ESTIMATION)


def test_the_pose_estimation_runs_on_hmd_beside_the_camera(live):
    """Placement (docs/architecture.md): the pose estimation beside the camera whose features
    it reads; as that section describes this split, the fusion beside the application (hmd),
    and the A.R.T. chain's inversion beside the A.R.T. tracker (room): the chain's output
    crosses to hmd, one stream."""
    d = live
    status = d.wait_for(lambda s: pose_estimation_hosts(s) and s, RECOVERY_S, "all placed")
    hosts = pose_estimation_hosts(status)
    assert hosts == {"hmd"}, f"pose estimation on {hosts}\n{d.explain()}"
    assert hosts_of(status, "fusion") == {"hmd"}, d.explain()
    assert hosts_of(status, "inversion") == {"room"}, d.explain()


def test_the_camera_clock_ahead_is_measured_and_aligned_where_it_meets_the_art(live):
    """hmd's host manager measures its clock 200 ms ahead; the fusion, where the camera's
    stream (hmd's clock) meets the A.R.T.'s (room's, the agent's), carries that offset on the
    camera's input, and the relation stays true (the first test's bounds, checked again)."""
    d = live

    def aligned(status: dict) -> dict | None:
        clock = (status.get("host_info", {}).get("hmd") or {}).get("clock")
        fusions = [c for c in status["components"].values() if c["service"] == "fusion"]
        offsets = [  # of the estimates fused (not the static edge its output is composed with)
            b.get("clock_offset_ns", 0) for f in fusions for b in f["inputs"] if b["port"] == "AB"
        ]
        return {"clock": clock, "offsets": offsets} if clock and any(offsets) else None

    seen = d.wait_for(aligned, RECOVERY_S, "hmd's clock measured and the fusion aligned")
    ahead_ns = HMD_CLOCK_AHEAD_MS * 1e6
    assert abs(seen["clock"]["offset_ns"] + ahead_ns) <= seen["clock"]["uncertainty_ns"], seen
    tolerance = seen["clock"]["uncertainty_ns"] * 2
    assert sorted(abs(o + ahead_ns) <= tolerance for o in seen["offsets"]) == [False, True], seen
    assert d.status()["clock_problems"] == {}, d.explain()
    d.assert_true(d.fresh_samples(RECOVERY_S))


def test_a_killed_host_manager_leaves_its_workers_and_the_flow_running(live):
    d = live
    on_hmd = d.wait_for(
        lambda s: {i for i, h in placed(s).items() if h == "hmd"}, RECOVERY_S, "workers on hmd"
    )
    pids = d.worker_pids(on_hmd)
    host = d.net.processes["host-hmd"]
    os.kill(host.pid, signal.SIGKILL)
    host.wait()
    d.wait_for(lambda s: "hmd" not in s["hosts"], RECOVERY_S, "host manager hmd gone")
    d.assert_true(d.fresh_samples(RECOVERY_S))
    now = d.worker_pids(on_hmd)
    assert now == pids, f"workers of hmd before {pids}, after {now}\n{d.explain()}"
    d.start_host("hmd")
    d.wait_for(lambda s: "hmd" in s["hosts"], RECOVERY_S, "host manager hmd back")


def elsewhere(status: dict, pose_estimation: bool) -> dict[str, str | None]:
    """Where each component runs, once every one is alive on a live host other than hmd and
    the pose estimation is among them (or, if not ``pose_estimation``, not among them)."""
    where = placed(status)
    services = {c["service"] for c in status["components"].values()}
    live = set(status["hosts"]) - {"hmd"}
    wanted = (POSE_ESTIMATION in services) == pose_estimation
    return where if wanted and set(where.values()) <= live else {}


def test_when_hmds_workers_fail_they_move_to_a_live_host(live):
    """The host manager of hmd and every worker it ran (those of the previous test too) are
    killed; the camera, on a device of its own, stays: the pose estimation runs elsewhere."""
    d = live
    assert d.fail_workers("hmd"), d.explain()
    d.wait_for(
        lambda s: elsewhere(s, pose_estimation=True),
        RECOVERY_S,
        "every component alive on a live host, the pose estimation among them, none on hmd",
    )
    d.assert_true(d.fresh_samples(RECOVERY_S))
    d.start_host("hmd")
    d.wait_for(lambda s: "hmd" in s["hosts"], RECOVERY_S, "host manager hmd back")


def test_when_the_machine_hmd_fails_the_flow_returns_and_so_does_the_machine(live):
    """Every process of hmd but the application (the test's observer) is killed: its host
    manager, its workers and the camera. The components still wanted (the A.R.T. path) run
    on a live host and the relation flows; the machine back (camera, host manager), the pose
    estimation returns."""
    d = live
    camera = d.others.pop("camera")
    assert camera in d.fail_workers("hmd"), d.explain()
    d.wait_for(
        lambda s: elsewhere(s, pose_estimation=False),
        RECOVERY_S,
        "every component alive on a live host, none on hmd, no pose estimation (no camera)",
    )
    d.assert_true(d.fresh_samples(RECOVERY_S))
    d.other("hmd", "camera", "sim", "camera", *d.scenario_flags)
    d.start_host("hmd")
    d.wait_for(pose_estimation_hosts, RECOVERY_S, "the pose estimation back, placed")
    d.assert_true(d.fresh_samples(RECOVERY_S))


def test_a_cut_cable_heals_and_the_relation_flows_again(live):
    d = live
    d.fresh_samples(RECOVERY_S, count=5)
    d.net.link_down("hmd")
    time.sleep(CUT_S)  # the cut itself, not a measurement
    d.net.link_up("hmd")
    d.assert_true(d.fresh_samples(RECOVERY_S))


def test_a_partition_longer_than_the_lease_heals(live):
    """Cut for longer than zenoh's lease: the router drops hmd's clients, the agent sees its
    host manager, the camera and the application's query vanish; plugged back, they
    reconnect and declare themselves again, and the relation flows again."""
    d = live
    d.fresh_samples(RECOVERY_S, count=5)
    d.net.link_down("hmd")
    d.wait_for(lambda s: "hmd" not in s["hosts"], RECOVERY_S, "hmd dropped by the router")
    d.net.link_up("hmd")
    d.wait_for(lambda s: "hmd" in s["hosts"], RECOVERY_S, "hmd back")
    d.assert_true(d.fresh_samples(RECOVERY_S))


def test_a_host_joining_later_is_seen_and_used_when_needed(live):
    d = live
    d.start_host("extra")
    d.wait_for(lambda s: "extra" in s["hosts"], RECOVERY_S, "host manager extra seen")
    for machine in ("room", "hmd"):
        d.fail_workers(machine)

    def on_extra(status: dict) -> bool:
        where = placed(status)
        return status["hosts"] == ["extra"] and bool(where) and set(where.values()) == {"extra"}

    d.wait_for(on_extra, RECOVERY_S, "every component on extra, the only live host")
    d.assert_true(d.fresh_samples(RECOVERY_S))
