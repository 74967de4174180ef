"""Zenoh settings, resolved in one place from defaults, a file, the environment and CLI flags.

Precedence, lowest first: built-in defaults for the process's role, the YAML file named by
``--config`` or ``UBITRACK_CONFIG``, ``UBITRACK_*`` environment variables, command-line flags.

The embedded default needs no router and no Docker: every process is a zenoh **peer** on
loopback with multicast scouting off. The agent (role ``hub``) listens on the well-known
port :data:`DEFAULT_HUB_PORT`; every other process (role ``member``) listens on a random
loopback port and connects to the hub, retrying in the background until it appears, so
processes can start in any order. Gossip scouting then lets members connect to each other
directly. A multi-host setup only changes ``connect``/``listen``; with zenoh routers (role
``router``, ``ubitrack router``), every other process is a ``client`` of its site's router.

Opt-in security (``docs/security.md``): ``tls_root_ca``, ``tls_certificate`` and ``tls_key``
make every link TLS with client certificates (mutual TLS); ``access_control`` names a file
holding zenoh's ``access_control`` block (``net.access`` builds it), for the hub, a router
that every member reaches as a client, so that it sees every message.

``host_name`` says which machine a process runs on (default: the machine's host name): the
agent places workers near the data they read (``agent/placement.py``). ``clock_offset_ms`` is
for tests only: it makes a process's clock read that much ahead, as on a host whose clock is
off (``net/clock.py``).

This module is pure; :mod:`ubitrack_agent.net.session` turns :class:`Settings` into a session.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import socket
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Literal

import yaml

from ubitrack_agent.net.keys import validate_key_chunks

Role = Literal["hub", "member", "router"]

DEFAULT_HUB_PORT = 7448
"""Loopback port the agent listens on by default (7447 is left to a router)."""
DEFAULT_ROUTER_PORT = 7447
"""Port a router (``ubitrack router``, role ``router``) listens on by default: zenoh's own."""

MODES = ("peer", "client", "router")
_ENDPOINT = re.compile(r"^(tcp|udp|tls|quic|ws|unixsock-stream|unixpipe|serial)/\S+$")


DROP_WAIT_US = 10_000
"""How long a put waits for room in a full transmission queue before zenoh drops it (its
``transport/link/tx/queue/congestion_control/drop/wait_before_drop``, in microseconds; zenoh's
default 1 ms). Every put of the data path drops rather than waits (``net.transport``, "Nothing
waits for a reader"): after this wait the queue counts as congested and later droppable
messages on it are dropped at once until a batch is sent, so a reader that stopped reading
costs whoever routes to it this long once, not the 5 s a waiting put (BLOCK) held them
(``docs/performance.md``, "A stalled reader holds nobody (session 27)"). 10 ms rather than 1:
with it, zenoh lost no sample at 2,000-10,000 samples/s where 1 ms lost 0.1-1.0 % at 10,000
(``docs/performance.md``, "Zenoh's own options on the data path (session 23)", ``drop10``)."""


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
    tls_root_ca: str | None = None
    tls_certificate: str | None = None
    tls_key: str | None = None
    access_control: str | None = None
    host_name: str = field(default_factory=lambda: default_host_name())
    clock_offset_ms: float = 0.0

    @property
    def tls(self) -> bool:
        """Whether links are mutual TLS (the three ``tls_*`` files are given together)."""
        return self.tls_root_ca is not None

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
            # A client cannot open without its router (zenoh's default gives up at once):
            # wait for it as long as it takes, so processes still start in any order.
            **({"connect/timeout_ms": -1} if self.mode == "client" else {}),
            "transport/link/tx/queue/congestion_control/drop/wait_before_drop": DROP_WAIT_US,
            **self._security_options(),
        }

    def _security_options(self) -> dict[str, Any]:
        """The TLS and access-control entries, when configured."""
        options: dict[str, Any] = {}
        if self.tls:
            options["transport/link/tls"] = {
                "root_ca_certificate": self.tls_root_ca,
                "listen_certificate": self.tls_certificate,
                "listen_private_key": self.tls_key,
                "connect_certificate": self.tls_certificate,
                "connect_private_key": self.tls_key,
                "enable_mtls": True,
            }
        if self.access_control is not None:
            options["access_control"] = load_access_control(self.access_control)
        return options


MAX_CLOCK_OFFSET_MS = 86_400_000.0
"""Largest ``clock_offset_ms`` accepted (a day)."""
MAX_CLOCK_OFFSET_NS = 86_400 * 10**9
"""The same in nanoseconds: the largest clock offset the middleware handles (``net.clock``,
an input's ``clock_offset_ns`` in ``net.spec``)."""


def default_host_name() -> str:
    """The machine's host name as a key chunk: its first label if the whole name breaks the
    name rule (a host name is letters, digits, ``-`` and ``.``, so this is rare), else
    ``host``."""
    name = socket.gethostname()
    for candidate in (name, name.split(".", 1)[0]):
        try:
            return validate_key_chunks(candidate, single_chunk=True)
        except ValueError:
            continue
    return "host"


MEMBER_LISTEN = ("tcp/127.0.0.1:0",)
"""Where a member peer listens by default: a random loopback port."""


def defaults(role: Role) -> Settings:
    """The embedded default for a role (see the module docstring); a router's is a router on
    loopback, port :data:`DEFAULT_ROUTER_PORT` (its settings file opens it to other machines)."""
    hub = f"tcp/127.0.0.1:{DEFAULT_HUB_PORT}"
    if role == "hub":
        return Settings(listen=(hub,))
    if role == "router":
        return Settings(mode="router", listen=(f"tcp/127.0.0.1:{DEFAULT_ROUTER_PORT}",))
    return Settings(connect=(hub,), listen=MEMBER_LISTEN)


def member_of(hub: Settings) -> Settings:
    """Settings of a process joining ``hub``'s network and domain, with the hub's TLS files:
    it connects where the hub listens (a wildcard address as loopback; not a random port),
    then where the hub connects (a router, or the other agents: the child of a standby agent
    must not depend on the agent it connects to, which may be the one that died). It is a
    client, listening nowhere, when the hub enforces access control (so that every message
    passes the hub) or is itself a client; else a peer, even when the hub is a router,
    listening on a random loopback port."""
    own = tuple(
        endpoint.replace("0.0.0.0", "127.0.0.1")
        for endpoint in hub.listen
        if not endpoint.endswith(":0")  # a random port: nobody can be told where
    )
    connect = tuple(dict.fromkeys((*own, *hub.connect)))
    client = hub.access_control is not None or hub.mode == "client"
    return replace(
        hub,
        mode="client" if client else "peer",
        connect=connect,
        listen=() if client else MEMBER_LISTEN,
        access_control=None,
    )


def client_of(host: Settings, gateway: str) -> Settings:
    """Settings of a process joining the network as a zenoh client of the peer ``host`` (a
    host manager) at its endpoint ``gateway``: one link, listening nowhere, instead of a peer
    linked to every other (gossip scouting makes the peers a full mesh: a process's links grow
    with the processes, their total with their square). ``host``'s own connect endpoints
    follow, tried when the gateway is gone (zenoh 1.10's peers forward between the network and
    their clients: ``docs/services.md``, "Links")."""
    member = member_of(host)
    return replace(
        member, mode="client", connect=tuple(dict.fromkeys((gateway, *member.connect))), listen=()
    )


def as_flags(settings: Settings) -> list[str]:
    """The command-line flags (:func:`add_arguments`) that resolve to ``settings``; how a
    process hands its network to a child process."""
    flags = ["--mode", settings.mode, "--prefix", settings.prefix, "--domain", settings.domain]
    flags += ["--host-name", settings.host_name]
    if settings.clock_offset_ms:
        flags += ["--clock-offset-ms", repr(settings.clock_offset_ms)]
    for endpoint in settings.connect:
        flags += ["--connect", endpoint]
    for endpoint in settings.listen:
        flags += ["--listen", endpoint]
    for name in PATH_SETTINGS:
        if getattr(settings, name) is not None:
            flags += [_flag(name), getattr(settings, name)]
    return [*flags, "--multicast" if settings.multicast else "--no-multicast"]


def _flag(name: str) -> str:
    """The command-line flag of setting ``name``."""
    return "--" + name.replace("_", "-")


def child_environment(env: Mapping[str, str] | None = None) -> dict[str, str]:
    """The environment for a child process handed its network as flags (:func:`as_flags`):
    ``env`` (this process's) without the ``UBITRACK_*`` settings and ``UBITRACK_CONFIG``. The
    flags say everything but an empty setting (no endpoint to listen on, no access control),
    which the child would otherwise fill from this process's own: a worker listening on its
    agent's port (``Address already in use``), or enforcing its agent's access control."""
    env = os.environ if env is None else env
    ours = {ENV_PREFIX + name.upper() for name in SETTING_NAMES} | {ENV_PREFIX + "CONFIG"}
    return {name: value for name, value in env.items() if name not in ours}


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


def parse_clock_offset(where: str, value: Any) -> float:
    """A clock offset in milliseconds (a number within a day either way, text included), or
    ``ConfigError`` naming ``where``."""
    try:
        offset = float(value) if not isinstance(value, bool) else math.nan
    except (TypeError, ValueError):
        offset = math.nan
    if not math.isfinite(offset) or abs(offset) > MAX_CLOCK_OFFSET_MS:
        raise ConfigError(
            f"{where}: expected a number of milliseconds within +-{MAX_CLOCK_OFFSET_MS:.0f}, "
            f"got {value!r}"
        )
    return offset


PATH_SETTINGS = ("tls_root_ca", "tls_certificate", "tls_key", "access_control")
"""Settings naming a file; a relative path is relative to the settings file naming it (else to
the working directory), and becomes absolute, so child processes can be handed it."""


def _path(where: str, value: Any, base: Path) -> str:
    if not isinstance(value, str) or not value:
        raise ConfigError(f"{where}: expected a file name")
    path = (base / Path(value).expanduser()).resolve()
    if not path.is_file():
        raise ConfigError(f"{where}: {path} is not a readable file")
    return str(path)


def load_access_control(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Zenoh's ``access_control`` block from a JSON (or YAML) file (``net.access`` builds
    one); ``ConfigError`` if it is not a mapping."""
    block = load_file(path)
    if not block:
        raise ConfigError(f"{path}: expected zenoh's access_control block (a mapping)")
    return block


def _parse(source: str, name: str, value: Any, base: Path) -> Any:
    """Check one setting's value; ``source`` names its origin for error messages and ``base``
    is the directory relative file names start from."""
    where = f"{source}: {name}"
    if name in PATH_SETTINGS:
        return _path(where, value, base)
    if name == "mode":
        if value not in MODES:
            raise ConfigError(f"{where}: must be one of {', '.join(MODES)}, got {value!r}")
        return value
    if name in ("connect", "listen"):
        return _endpoints(where, value)
    if name == "multicast":
        return _boolean(where, value)
    if name == "clock_offset_ms":
        return parse_clock_offset(where, value)
    if not isinstance(value, str):
        raise ConfigError(f"{where}: expected a string, got {type(value).__name__}")
    try:
        validate_key_chunks(value, single_chunk=(name in ("domain", "host_name")))
    except ValueError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    return value


SETTING_NAMES = tuple(f.name for f in fields(Settings))


def _apply(settings: Settings, source: str, values: Mapping[str, Any], base: Path) -> Settings:
    unknown = sorted(set(values) - set(SETTING_NAMES))
    if unknown:
        raise ConfigError(f"{source}: unknown settings {unknown}; known: {list(SETTING_NAMES)}")
    return replace(settings, **{k: _parse(source, k, v, base) for k, v in values.items()})


def _checked(settings: Settings) -> Settings:
    """``settings`` if its security settings fit together, else ``ConfigError``."""
    given = [name for name in PATH_SETTINGS[:3] if getattr(settings, name) is not None]
    if given and len(given) < 3:
        raise ConfigError(
            f"tls_root_ca, tls_certificate and tls_key go together; only {given} given"
        )
    if settings.access_control is None:
        return settings
    if not settings.tls:
        raise ConfigError("access_control needs TLS: its subjects are certificate common names")
    plain = [e for e in settings.listen if not e.startswith("tls/")]
    if plain:
        raise ConfigError(f"access_control: listen on tls/ endpoints only, not {plain}")
    load_access_control(settings.access_control)
    return settings


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
    """Combine defaults < file < environment < flags (``None`` flag values are ignored). A
    client listens only where one of them says (zenoh's default), not on the member default."""
    env = os.environ if env is None else env
    config_file = config_file or env.get(ENV_PREFIX + "CONFIG")
    layers = [
        ("environment", from_environment(env), Path.cwd()),
        ("command line", {k: v for k, v in (flags or {}).items() if v is not None}, Path.cwd()),
    ]
    if config_file:
        layers.insert(0, (str(config_file), load_file(config_file), Path(config_file).parent))
    settings = defaults(role)
    for source, values, base in layers:
        settings = _apply(settings, source, values, base)
    if settings.mode == "client" and not any("listen" in values for _, values, _ in layers):
        settings = replace(settings, listen=())
    return _checked(settings)


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
    group.add_argument(
        "--host-name",
        metavar="NAME",
        help="the host this process runs on, for placing workers near their data "
        "(default: the machine's host name)",
    )
    group.add_argument(
        "--clock-offset-ms",
        metavar="MS",
        help="for tests: this process's clock reads this much ahead of the real one "
        "(a host whose clock is off; default: 0)",
    )
    group.add_argument("--tls-root-ca", metavar="FILE", help="CA certificate (PEM): mutual TLS")
    group.add_argument("--tls-certificate", metavar="FILE", help="this process's certificate")
    group.add_argument("--tls-key", metavar="FILE", help="this process's private key")
    group.add_argument(
        "--access-control",
        metavar="FILE",
        help="zenoh access_control block (JSON) a hub enforces (docs/security.md)",
    )


def from_arguments(args: argparse.Namespace, role: Role) -> Settings:
    """Resolve settings for a subcommand parsed with :func:`add_arguments`."""
    flags = {name: getattr(args, name, None) for name in SETTING_NAMES}
    return resolve(role, config_file=args.config, flags=flags)
