"""docker/ is right by construction: every container runs a command the CLI accepts and is
restarted when it exits, docker-compose (where installed) accepts the files, and the
containers of the variant over several machines (compose.hosts.yaml) resolve their settings
to clients of one router, each naming its machine."""

import os
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

from ubitrack_agent import cli
from ubitrack_agent.cli import build_parser
from ubitrack_agent.commands.router import router_settings
from ubitrack_agent.net import config

DOCKER = Path(__file__).resolve().parents[2] / "docker"


def test_every_service_runs_a_valid_ubitrack_command():
    compose = yaml.safe_load((DOCKER / "compose.yaml").read_text())
    parser = build_parser()
    assert {"agent", "database", "camera", "dtrack", "art", "application"} <= set(
        compose["services"]
    )
    for name, service in compose["services"].items():
        assert service["image"] == "ubitrack-agent:latest", name
        parser.parse_args(service["command"])  # exits (SystemExit) on a bad command
    entrypoint = [
        line
        for line in (DOCKER / "Dockerfile").read_text().splitlines()
        if line.startswith("ENTRYPOINT")
    ]
    assert entrypoint == ['ENTRYPOINT ["ubitrack"]']


def test_the_image_installs_the_package_as_users_do():
    """A normal install (the wheel's package data), not an editable one beside the sources."""
    text = (DOCKER / "Dockerfile").read_text()
    installs = [line for line in text.splitlines() if "pip install" in line]
    assert installs and all(" -e " not in line and "editable" not in line for line in installs)
    copied = {
        source
        for line in text.splitlines()
        if line.startswith("COPY")
        for source in line.split()[1:-1]
    }
    build = {"pyproject.toml", "setup.py", "README.md"}  # setup.py maps the folders (see there)
    assert build | {"ubitrack_agent", "services", "sim_trackers", "templates"} <= copied


RESTART = "unless-stopped"
"""Every container's restart policy: restarted whenever it exits, unless stopped by hand."""


@pytest.mark.parametrize("file", ["compose.yaml", "compose.hosts.yaml"])
def test_every_service_is_restarted_when_it_exits(file):
    compose = yaml.safe_load((DOCKER / file).read_text())
    assert {name: service.get("restart") for name, service in compose["services"].items()} == (
        dict.fromkeys(compose["services"], RESTART)
    )


def resolved_services(*files: str) -> dict:
    """The services as docker-compose resolves ``files`` (merged, anchors expanded)."""
    arguments = [argument for name in files for argument in ("-f", str(DOCKER / name))]
    result = subprocess.run(
        ["docker-compose", *arguments, "config"], capture_output=True, text=True
    )
    assert result.returncode == 0, result.stderr
    return yaml.safe_load(result.stdout)["services"]


@pytest.mark.skipif(shutil.which("docker-compose") is None, reason="docker-compose not installed")
@pytest.mark.parametrize(
    "files", [("compose.yaml",), ("compose.yaml", "compose.tls.yaml"), ("compose.hosts.yaml",)]
)
def test_docker_compose_accepts_the_files_and_keeps_the_restart_policy(files):
    services = resolved_services(*files)
    assert {name: service["restart"] for name, service in services.items()} == dict.fromkeys(
        services, RESTART
    )


def _certs_command(compose_file: Path) -> list[str]:
    """The ``ubitrack certs`` arguments the file's header says to run first."""
    lines = compose_file.read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if "ubitrack certs" in line)
    words = " ".join(line.lstrip("# ").rstrip("\\") for line in lines[start : start + 2]).split()
    return words[words.index("certs") :]


@pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl not installed")
def test_the_tls_variant_hands_every_zenoh_service_valid_secure_settings(tmp_path, monkeypatch):
    """Every container of compose.tls.yaml resolves its settings (files made by the header's
    command, then its environment, then its command's flags) to mutual TLS: the agent a
    router enforcing the access control, the others clients listening nowhere."""
    command = _certs_command(DOCKER / "compose.tls.yaml")
    assert cli.main([*(str(tmp_path) if w == "docker/certs" else w for w in command)]) == 0
    base = yaml.safe_load((DOCKER / "compose.yaml").read_text())["services"]
    override = yaml.safe_load((DOCKER / "compose.tls.yaml").read_text())["services"]
    assert set(override) == set(base) - {"art"}  # every zenoh process; art speaks UDP only
    parser = build_parser()
    for name, service in override.items():
        assert "./certs:/etc/ubitrack:ro" in service["volumes"], name
        env = {**base[name].get("environment", {}), **service["environment"]}
        env["UBITRACK_CONFIG"] = env["UBITRACK_CONFIG"].replace("/etc/ubitrack", str(tmp_path))
        args = parser.parse_args(service.get("command", base[name]["command"]))
        monkeypatch.setattr(os, "environ", env)
        settings = config.from_arguments(args, role="hub" if name == "agent" else "member")
        assert settings.tls and settings.domain == "lab", name
        if name == "agent":
            assert settings.mode == "router" and settings.access_control is not None
        else:
            assert (settings.mode, settings.connect, settings.listen) == (
                "client",
                ("tls/agent:7448",),
                (),
            )


HOSTS = {
    "router": None,
    "agent": "room",
    "host-room": "room",
    "database": "room",
    "dtrack": "room",
    "art": None,
    "host-hmd": "hmd",
    "camera": "hmd",
    "application": "hmd",
}
"""compose.hosts.yaml's services and the machine each names (None: no zenoh client)."""


def test_the_variant_over_two_machines_meets_at_one_router(monkeypatch):
    """compose.hosts.yaml: the same image, valid commands; the router listens for every
    machine; every other zenoh process is a client of it naming its machine, the host
    managers named after theirs; the agent runs no host manager of its own."""
    services = yaml.safe_load((DOCKER / "compose.hosts.yaml").read_text())["services"]
    assert set(services) == set(HOSTS)
    parser = build_parser()
    for name, service in services.items():
        assert service["image"] == "ubitrack-agent:latest", name
        args = parser.parse_args(service["command"])
        monkeypatch.setattr(os, "environ", dict(service.get("environment", {})))
        if name == "router":
            settings = router_settings(args)
            assert settings.listen == ("tcp/0.0.0.0:7447",) and settings.connect == ()
            assert "7447:7447" in service["ports"]
        elif HOSTS[name] is not None:
            settings = config.from_arguments(args, role="hub" if name == "agent" else "member")
            assert (settings.mode, settings.connect, settings.listen) == (
                "client",
                ("tcp/router:7447",),
                (),
            ), name
            assert (settings.domain, settings.host_name) == ("lab", HOSTS[name]), name
        if args.command == "host":
            assert args.name == HOSTS[name], name
    assert parser.parse_args(services["agent"]["command"]).no_host
