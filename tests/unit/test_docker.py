"""docker/ is right by construction: every container runs a command the CLI accepts, and
docker-compose (where installed) accepts the file."""

import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

from ubitrack_agent.cli import build_parser

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
    copied = {line.split()[1] for line in text.splitlines() if line.startswith("COPY")}
    assert {"ubitrack_agent", "services", "sim_trackers", "templates"} <= copied


@pytest.mark.skipif(shutil.which("docker-compose") is None, reason="docker-compose not installed")
def test_docker_compose_accepts_the_file():
    result = subprocess.run(
        ["docker-compose", "-f", str(DOCKER / "compose.yaml"), "config", "--quiet"],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 0, result.stderr
