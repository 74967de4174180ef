"""``ubitrack certs``: a throw-away CA, a certificate per role and provider, the access-control
file and one settings file per process kind, for the opt-in secure setup (``docs/security.md``).

Certificates are made with the ``openssl`` command-line tool (P-256 keys; no Python
dependency is added for it). An existing CA in the directory is kept, so running the command
again with another ``--provider`` adds that provider's certificate and updates the access
control without invalidating the certificates already handed out.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import yaml

from ubitrack_agent.net import access, config
from ubitrack_agent.net.keys import KeySpace, validate_key_chunks

CA_NAME = "ubitrack throw-away CA"
ACCESS_CONTROL_FILE = "access-control.json"
HUB_NAMES = ("localhost", "127.0.0.1")
"""Names every hub certificate is valid for, beside ``--hub-host``."""


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "certs",
        help="make a throw-away CA, certificates and settings for mutual TLS + access control",
        description="Write to DIR: ca.pem, <name>.pem and <name>-key.pem for the roles "
        f"{', '.join(access.ROLES)} and every --provider, {ACCESS_CONTROL_FILE} (zenoh's "
        "access control for the prefix and domain) and <name>.yaml settings (agent.yaml: the "
        "hub, a zenoh router enforcing it; the others: clients connecting to it). Keeps an "
        "existing CA in DIR. See docs/security.md.",
    )
    parser.add_argument("directory", metavar="DIR", type=Path)
    parser.add_argument(
        "--provider",
        action="append",
        default=[],
        metavar="ID",
        help="a provider id (sensor, database, store) that gets a certificate, repeatable",
    )
    parser.add_argument(
        "--hub-host",
        action="append",
        default=[],
        metavar="NAME",
        help="a DNS name or address of the agent's machine, repeatable; the first is where "
        "the clients' settings connect (default: localhost)",
    )
    parser.add_argument("--hub-port", type=int, default=config.DEFAULT_HUB_PORT)
    parser.add_argument("--prefix", default="ubitrack", help="key prefix (default: ubitrack)")
    parser.add_argument("--domain", default="default", help="key domain (default: default)")
    parser.add_argument("--days", type=int, default=30, help="validity (default: 30 days)")
    parser.set_defaults(func=run)


def _openssl(*arguments: str) -> None:
    """Run ``openssl``; ``RuntimeError`` with its message if it fails."""
    result = subprocess.run(["openssl", *arguments], capture_output=True, text=True)
    if result.returncode != 0:
        raise RuntimeError(f"openssl {arguments[0]}: {result.stderr.strip()}")


def _new_certificate(directory: Path, name: str, common_name: str, days: int) -> list[str]:
    """``openssl`` arguments writing a new key ``<name>-key.pem`` and its certificate
    ``<name>.pem`` for ``common_name`` (self-signed unless ``-CA`` follows)."""
    return [
        *("req", "-x509", "-new", "-nodes", "-days", str(days), "-subj", f"/CN={common_name}"),
        *("-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256"),
        *("-keyout", str(directory / f"{name}-key.pem"), "-out", str(directory / f"{name}.pem")),
    ]


def make_ca(directory: Path, days: int) -> None:
    """Write ``ca.pem`` and ``ca-key.pem`` unless the CA is there already."""
    if (directory / "ca.pem").is_file() and (directory / "ca-key.pem").is_file():
        return
    _openssl(
        *_new_certificate(directory, "ca", CA_NAME, days),
        *("-addext", "basicConstraints=critical,CA:TRUE"),
        *("-addext", "keyUsage=critical,keyCertSign,cRLSign"),
    )


def issue(directory: Path, name: str, days: int, hosts: Sequence[str] = ()) -> None:
    """Write ``<name>.pem`` (common name ``name``, signed by the CA in ``directory``, for
    client use, and for server use on ``hosts`` if any) and ``<name>-key.pem``."""
    names = ",".join(f"IP:{h}" if h.replace(".", "").isdigit() else f"DNS:{h}" for h in hosts)
    _openssl(
        *_new_certificate(directory, name, name, days),
        *("-CA", str(directory / "ca.pem"), "-CAkey", str(directory / "ca-key.pem")),
        *("-addext", "basicConstraints=critical,CA:FALSE"),
        *("-addext", "keyUsage=critical,digitalSignature"),
        *("-addext", "extendedKeyUsage=serverAuth,clientAuth"),
        *(("-addext", f"subjectAltName={names}") if names else ()),
    )
    (directory / f"{name}-key.pem").chmod(0o600)


def settings_files(
    names: Sequence[str], connect_host: str, port: int, prefix: str, domain: str
) -> dict[str, dict[str, object]]:
    """The settings file of each name (relative file names): ``agent`` is the hub, a router
    enforcing the access control on TLS; every other name a client connecting to it."""
    files: dict[str, dict[str, object]] = {}
    for name in names:
        common = {
            "tls_root_ca": "ca.pem",
            "tls_certificate": f"{name}.pem",
            "tls_key": f"{name}-key.pem",
            "prefix": prefix,
            "domain": domain,
        }
        if name == access.AGENT:
            files[name] = {
                "mode": "router",
                "listen": [f"tls/0.0.0.0:{port}"],
                "access_control": ACCESS_CONTROL_FILE,
                **common,
            }
        else:
            files[name] = {"mode": "client", "connect": [f"tls/{connect_host}:{port}"], **common}
    return files


def generate(args: argparse.Namespace) -> list[str]:
    """Write everything; the names certified."""
    validate_key_chunks(args.domain, single_chunk=True)
    keys = KeySpace(f"{args.prefix}/{args.domain}")
    block = access.access_control(keys, args.provider)  # checks the names first
    names = [*access.ROLES, *args.provider]
    directory: Path = args.directory
    directory.mkdir(parents=True, exist_ok=True)
    make_ca(directory, args.days)
    hub_hosts = [*HUB_NAMES, *args.hub_host]
    for name in names:
        issue(directory, name, args.days, hub_hosts if name == access.AGENT else ())
    (directory / ACCESS_CONTROL_FILE).write_text(json.dumps(block, indent=2) + "\n")
    connect_host = (args.hub_host or ["localhost"])[0]
    files = settings_files(names, connect_host, args.hub_port, args.prefix, args.domain)
    for name, settings in files.items():
        (directory / f"{name}.yaml").write_text(yaml.safe_dump(settings, sort_keys=False))
    return names


def run(args: argparse.Namespace) -> int:
    if shutil.which("openssl") is None:
        print("ubitrack certs: needs the openssl command-line tool", file=sys.stderr)
        return 2
    try:
        names = generate(args)
    except (ValueError, RuntimeError, OSError) as exc:
        print(f"ubitrack certs: {exc}", file=sys.stderr)
        return 2
    print(f"ubitrack certs: {', '.join(names)} in {args.directory} (keep ca-key.pem offline)")
    return 0
