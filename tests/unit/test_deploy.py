"""deploy/ is right by construction: each unit of deploy/systemd/ restarts its process, runs
it unprivileged with its settings file, and runs a command the CLI accepts; the agent's and the
host manager's units signal only their main process, so the workers outlive a restart and are
adopted (docs/operations.md); systemd-analyze (where installed) accepts every unit; and the
settings files of a deployment with routers resolve to what docs/operations.md says."""

import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from ubitrack_agent.cli import build_parser
from ubitrack_agent.commands.router import router_settings
from ubitrack_agent.net import config

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"
SYSTEMD = DEPLOY / "systemd"
INSTALLED = "/opt/ubitrack/bin/ubitrack"
"""Where docs/operations.md installs the command; every unit runs it."""
UNITS = (
    "ubitrack-agent.service",
    "ubitrack-host.service",
    "ubitrack-dtrack@.service",
    "ubitrack-router.service",
)
PARENTS = ("ubitrack-agent.service", "ubitrack-host.service")
"""Units whose process starts workers."""
INSTANCE = "ART"
"""The instance name the template units are checked with."""


def directives(unit: str) -> dict[str, list[str]]:
    """``Section.Key`` -> every value the unit file gives it, in order."""
    found: dict[str, list[str]] = {}
    section = ""
    for line in (SYSTEMD / unit).read_text().splitlines():
        line = line.strip()
        if line.startswith("[") and line.endswith("]"):
            section = line[1:-1]
        elif line and not line.startswith("#"):
            key, _, value = line.partition("=")
            found.setdefault(f"{section}.{key}", []).append(value)
    return found


def instantiated(text: str, executable: str) -> str:
    """A unit's text with ``%i`` replaced by an instance name and the installed command by
    ``executable``."""
    return text.replace("%i", INSTANCE).replace(INSTALLED, executable)


def test_the_units_shipped_are_the_ones_documented():
    assert sorted(path.name for path in SYSTEMD.iterdir()) == sorted(UNITS)
    operations = (SYSTEMD.parents[1] / "docs" / "operations.md").read_text()
    assert all(unit in operations for unit in UNITS)


@pytest.mark.parametrize("unit", UNITS)
def test_every_unit_restarts_an_unprivileged_process_with_its_settings_file(unit):
    found = directives(unit)
    assert found["Service.Restart"] == ["always"]
    assert found["Service.RestartSec"] == ["1s"]
    assert found["Service.RestartPreventExitStatus"] == ["2"]  # bad options: no restart loop
    assert found["Unit.StartLimitIntervalSec"] == ["0"]  # never gives up restarting
    assert found["Service.User"] == ["ubitrack"]
    assert found["Service.NoNewPrivileges"] == ["yes"]
    assert any(
        value.startswith("UBITRACK_CONFIG=/etc/ubitrack/") for value in found["Service.Environment"]
    )


@pytest.mark.parametrize("unit", UNITS)
def test_every_unit_runs_a_valid_ubitrack_command(unit):
    (command,) = directives(unit)["Service.ExecStart"]
    words = shlex.split(instantiated(command, INSTALLED).replace("$DTRACK_ARGS", "--body 0=WT"))
    assert words[0] == INSTALLED
    build_parser().parse_args(words[1:])  # exits (SystemExit) on a bad command


@pytest.mark.parametrize("unit", PARENTS)
def test_restarting_the_agent_or_a_host_manager_leaves_the_workers_running(unit):
    """KillMode=process: systemd signals the main process alone, never the workers in the
    unit's control group (control-group or mixed would kill them when the main process dies)."""
    assert directives(unit)["Service.KillMode"] == ["process"]


@pytest.mark.skipif(
    shutil.which("systemd-analyze") is None,
    reason="systemd-analyze not installed (Debian: apt-get install systemd; .ci/run does)",
)
@pytest.mark.parametrize("unit", UNITS)
def test_systemd_analyze_accepts_the_unit(unit, tmp_path):
    """Verified with this environment's ``ubitrack`` in place of the installed one (verify
    checks that the command exists); systemd reports unknown keys as warnings, so any output
    fails the test."""
    executable = str(Path(sys.executable).with_name("ubitrack"))
    copy = tmp_path / unit.replace("@.", f"@{INSTANCE}.")
    copy.write_text(instantiated((SYSTEMD / unit).read_text(), executable))
    result = subprocess.run(
        ["systemd-analyze", "verify", str(copy)], capture_output=True, text=True
    )
    assert result.returncode == 0 and not result.stderr.strip(), result.stderr


def test_the_router_settings_files_make_linked_routers_and_their_members_clients():
    """deploy/router.yaml: a router open to the site's machines; router-site2.yaml: a second
    site's router linked to the first; member.yaml: every other process a client of its
    site's router, listening nowhere."""
    parser = build_parser("router")
    first, second = (
        router_settings(parser.parse_args(["router", "--config", str(DEPLOY / name)]))
        for name in ("router.yaml", "router-site2.yaml")
    )
    port = config.DEFAULT_ROUTER_PORT
    assert (first.mode, first.listen, first.connect) == ("router", (f"tcp/0.0.0.0:{port}",), ())
    assert second.listen == first.listen and len(second.connect) == 1
    assert second.connect[0].endswith(f":{port}")
    for role in ("hub", "member"):  # the agent and every other process
        member = config.resolve(role, config_file=DEPLOY / "member.yaml", env={})
        assert (member.mode, member.listen, member.connect) == ("client", (), second.connect)
        assert member.zenoh_options()["connect/timeout_ms"] == -1  # waits for its router
