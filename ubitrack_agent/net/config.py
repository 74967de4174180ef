"""Zenoh settings, resolved in one place from defaults, a file, the environment and CLI flags.

Precedence, lowest first: built-in defaults for the process's role, the YAML file named by
``--config`` or ``UBITRACK_CONFIG``, ``UBITRACK_*`` environment variables, command-line flags.

The embedded default needs no router and no Docker: every process is a zenoh **peer** on
loopback with multicast scouting off. The agent (role ``hub``) listens on the well-known
port :data:`DEFAULT_HUB_PORT`; every other process (role ``member``) listens on a random
loopback port and connects to the hub, retrying in the background until it appears, so
processes can start in any order. Gossip scouting then lets members connect to each other
directly. A multi-host setup only changes ``connect``/``listen`` (or uses ``mode: client``
towards a router).

This module is pure; :mod:`ubitrack_agent.net.session` turns :class:`Settings` into a session.
"""

from __future__ import annotations

import argparse
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any, Literal

import yaml

from ubitrack_agent.net.keys import validate_key_chunks

Role = Literal["hub", "member"]

DEFAULT_HUB_PORT = 7448
"""Loopback port the agent listens on by default (7447 is left to a zenohd router)."""

MODES = ("peer", "client", "router")
_ENDPOINT = re.compile(r"^(tcp|udp|tls|quic|ws|unixsock-stream|unixpipe|serial)/\S+$")


class ConfigError(ValueError):
    """A setting is invalid; the message names where it came from (file, variable or flag)."""


@dataclass(frozen=True)
class Settings:
    """Everything a process needs to join the middleware's zenoh network."""

    mode: str = "peer"
    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    multicast: bool = False
    prefix: str = "ubitrack"
    domain: str = "default"

    @property
    def key_prefix(self) -> str:
        """Root of every key expression the middleware uses: ``<prefix>/<domain>``."""
        return f"{self.prefix}/{self.domain}"

    def zenoh_options(self) -> dict[str, Any]:
        """The zenoh configuration entries (path -> value) these settings stand for."""
        return {
            "mode": self.mode,
            "connect/endpoints": list(self.connect),
            "listen/endpoints": list(self.listen),
            "scouting/multicast/enabled": self.multicast,
            # Return from zenoh.open() at once (it otherwise waits up to 500 ms for scouting);
            # links come up in the background within milliseconds on loopback, and
            # publishers that must not lose their first samples wait for a subscriber.
            "scouting/delay": 0,
            # Reconnect quickly when the hub appears late or restarts.
            "connect/retry": {
                "period_init_ms": 100,
                "period_max_ms": 500,
                "period_increase_factor": 2,
            },
        }


def defaults(role: Role) -> Settings:
    """The embedded default for a role (see the module docstring)."""
    hub = f"tcp/127.0.0.1:{DEFAULT_HUB_PORT}"
    if role == "hub":
        return Settings(listen=(hub,))
    return Settings(connect=(hub,), listen=("tcp/127.0.0.1:0",))


def member_of(hub: Settings) -> Settings:
    """Settings of a process joining ``hub``'s network and domain: it connects where the hub
    connects (a router) or else where it listens (a wildcard address as loopback), listens on
    a random loopback port, and is a peer even when the hub is a router."""
    connect = hub.connect or tuple(
        endpoint.replace("0.0.0.0", "127.0.0.1") for endpoint in hub.listen
    )
    return replace(
        hub,
        mode="peer" if hub.mode == "router" else hub.mode,
        connect=connect,
        listen=("tcp/127.0.0.1:0",),
    )


def as_flags(settings: Settings) -> list[str]:
    """The command-line flags (:func:`add_arguments`) that resolve to ``settings``; how a
    process hands its network to a child process."""
    flags = ["--mode", settings.mode, "--prefix", settings.prefix, "--domain", settings.domain]
    for endpoint in settings.connect:
        flags += ["--connect", endpoint]
    for endpoint in settings.listen:
        flags += ["--listen", endpoint]
    return [*flags, "--multicast" if settings.multicast else "--no-multicast"]


def member_flags(hub: Settings) -> list[str]:
    """Flags making a child process join ``hub``'s network (:func:`member_of`)."""
    return as_flags(member_of(hub))


def _endpoints(source: str, value: Any) -> tuple[str, ...]:
    if isinstance(value, str):
        value = [part.strip() for part in value.split(",") if part.strip()]
    if not isinstance(value, list | tuple) or not all(isinstance(v, str) for v in value):
        raise ConfigError(f"{source}: expected a list of endpoints like 'tcp/127.0.0.1:7448'")
    for endpoint in value:
        if not _ENDPOINT.match(endpoint):
            raise ConfigError(
                f"{source}: {endpoint!r} is not a zenoh endpoint like 'tcp/host:port'"
            )
    return tuple(value)


def _boolean(source: str, value: Any) -> bool:
    if isinstance(value, bool):
        return value
    if isinstance(value, str) and value.lower() in ("1", "true", "yes", "on"):
        return True
    if isinstance(value, str) and value.lower() in ("0", "false", "no", "off"):
        return False
    raise ConfigError(f"{source}: expected true or false, got {value!r}")


def _parse(source: str, name: str, value: Any) -> Any:
    """Check one setting's value; ``source`` names its origin for error messages."""
    where = f"{source}: {name}"
    if name == "mode":
        if value not in MODES:
            raise ConfigError(f"{where}: must be one of {', '.join(MODES)}, got {value!r}")
        return value
    if name in ("connect", "listen"):
        return _endpoints(where, value)
    if name == "multicast":
        return _boolean(where, value)
    if not isinstance(value, str):
        raise ConfigError(f"{where}: expected a string, got {type(value).__name__}")
    try:
        validate_key_chunks(value, single_chunk=(name == "domain"))
    except ValueError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    return value


SETTING_NAMES = tuple(f.name for f in fields(Settings))


def _apply(settings: Settings, source: str, values: Mapping[str, Any]) -> Settings:
    unknown = sorted(set(values) - set(SETTING_NAMES))
    if unknown:
        raise ConfigError(f"{source}: unknown settings {unknown}; known: {list(SETTING_NAMES)}")
    return replace(settings, **{k: _parse(source, k, v) for k, v in values.items()})


def load_file(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read a YAML settings file: a mapping of setting names to values."""
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror})") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({exc})") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of settings")
    return data


ENV_PREFIX = "UBITRACK_"


def from_environment(env: Mapping[str, str]) -> dict[str, str]:
    """Settings given as ``UBITRACK_MODE``, ``UBITRACK_CONNECT`` (comma-separated), ..."""
    return {
        name: env[ENV_PREFIX + name.upper()]
        for name in SETTING_NAMES
        if ENV_PREFIX + name.upper() in env
    }


def resolve(
    role: Role,
    config_file: str | os.PathLike[str] | None = None,
    env: Mapping[str, str] | None = None,
    flags: Mapping[str, Any] | None = None,
) -> Settings:
    """Combine defaults < file < environment < flags (``None`` flag values are ignored)."""
    env = os.environ if env is None else env
    settings = defaults(role)
    config_file = config_file or env.get(ENV_PREFIX + "CONFIG")
    if config_file:
        settings = _apply(settings, str(config_file), load_file(config_file))
    settings = _apply(settings, "environment", from_environment(env))
    given = {k: v for k, v in (flags or {}).items() if v is not None}
    return _apply(settings, "command line", given)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the zenoh flags every networked subcommand shares."""
    group = parser.add_argument_group("zenoh network (override UBITRACK_* and --config)")
    group.add_argument("--config", metavar="FILE", help="YAML settings file")
    group.add_argument("--mode", choices=MODES, help="zenoh mode (default: peer)")
    group.add_argument(
        "--connect",
        metavar="ENDPOINT",
        action="append",
        help="endpoint to connect to, repeatable (default: the hub on loopback)",
    )
    group.add_argument(
        "--listen", metavar="ENDPOINT", action="append", help="endpoint to listen on, repeatable"
    )
    group.add_argument(
        "--multicast",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="multicast scouting (default: off)",
    )
    group.add_argument("--domain", help="key domain, ubitrack/<domain>/... (default: default)")
    group.add_argument("--prefix", help="key prefix (default: ubitrack)")


def from_arguments(args: argparse.Namespace, role: Role) -> Settings:
    """Resolve settings for a subcommand parsed with :func:`add_arguments`."""
    flags = {name: getattr(args, name, None) for name in SETTING_NAMES}
    return resolve(role, config_file=args.config, flags=flags)
