"""The host manager process: starts, stops and supervises the pattern workers of one machine
for the agent, which talks to it only over zenoh (``docs/protocol.md``, ``docs/services.md``).

Run ``python -m ubitrack_agent.services.host [--name NAME] [--pool-size N] [zenoh flags]``, or
``ubitrack host``; ``ubitrack agent`` starts one for its own machine unless given ``--no-host``. One
per machine, named after the machine by default; names must be unique in a domain.

A worker started cold is far slower to reach its liveliness token than one handed its
specification from the warm pool (:mod:`ubitrack_agent.services.supervisor`): it pays the
interpreter, the imports of numpy, scipy and OpenCV and the zenoh session (``python -m
bench.worker_start`` measures both; figures in ``docs/performance.md``, "Worker start-up").

The process ends on SIGTERM or SIGINT, terminating every worker it started. With
``--started-by-agent`` (how the agent starts it, with a pipe as standard input) it outlives
that agent: once the pipe closes (the agent died, stopped, or stood by for another) it serves
on, its containers, pool and worker links kept, for the agent's successor to adopt, and ends
once it has run no component and seen no active agent for a while (``ORPHAN_END_S``), or seen
no active agent for longer (``ABANDONED_END_S``), its components stopped
(:meth:`ubitrack_agent.services.host_manager.HostManager.orphan`).

Its worker processes (containers, pool members) join the network as zenoh **clients** of it,
one link each, where peers would each link to every other process (``docs/services.md``,
"Links"); ``--workers-as-peers`` makes them peers. Of host managers of one name started
together the first claim serves; the others, and one started while another serves, exit with
status 3 (``NAME_TAKEN``) saying which came first (:mod:`ubitrack_agent.services.host_claim`).
One started after a host manager of its name died adopts the containers that one left running
on this machine (:mod:`ubitrack_agent.services.adoption`).
"""

from __future__ import annotations

import argparse
import itertools
import logging
import os
import socket
import sys
import threading
import time
from dataclasses import replace
from typing import TYPE_CHECKING, Any, NoReturn

from ubitrack_agent.core.lines import write_line
from ubitrack_agent.core.names import parse_labels
from ubitrack_agent.net import config, logs
from ubitrack_agent.net.config import Settings
from ubitrack_agent.net.host_protocol import (
    DEFAULT_CAPACITY,
    MAX_CAPACITY,
    MAX_CORES,
    MAX_LABELS,
    HostInfo,
)
from ubitrack_agent.net.keys import KeySpace, validate_key_chunks
from ubitrack_agent.net.lifecycle import on_termination
from ubitrack_agent.net.status_line import periodic_status

if TYPE_CHECKING:
    import zenoh

    from ubitrack_agent.services.host_manager import HostManager

DEFAULT_POOL_SIZE = 2
"""Idle pool members by default: every component runs in a container (one per core), so a
member is taken only to start a container or restore one that died (issue 28: worker
processes at most the cores + 2)."""


ORPHAN_END_S = 30.0
"""A host manager whose agent is gone ends after running no component and seeing no active
agent this long: a successor agent (its process start, 0.4-6 s, then 1.5 s settling; 20 s seen
at a load of 29) adopts it with its warm pool; nothing waits for one that never comes."""
ABANDONED_END_S = 300.0
"""A host manager whose agent is gone ends, stopping its components, after seeing no active
agent this long even while it runs components: their applications' data goes on through an
agent's restart (seconds) and an upgrade (minutes), but an agent stopped for good (Ctrl-C on
``ubitrack agent``) leaves no process running for ever."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The host manager's own options (shared by ``python -m ubitrack_agent.services.host`` and
    ``ubitrack host``)."""
    parser.add_argument(
        "--name",
        help="this host manager's name, unique in the domain; its workers run under it "
        "(default: the --host-name setting, i.e. the machine's host name)",
    )
    parser.add_argument(
        "--labels",
        type=labels,
        default=frozenset(),
        help="comma-separated labels of this machine that templates may require, such as "
        "camera,gpu,hmd (default: none)",
    )
    parser.add_argument(
        "--capacity",
        type=int,
        default=DEFAULT_CAPACITY,
        help="components this host manager runs at most; further starts are refused "
        f"(default: %(default)s, 1 to {MAX_CAPACITY})",
    )
    parser.add_argument(
        "--cores",
        type=int,
        default=min(os.cpu_count() or 1, MAX_CORES),
        help="containers the agent runs this machine's components in (one process each, "
        "components of one derivation together; default: the machine's CPU cores, "
        f"%(default)s; 1 to {MAX_CORES})",
    )
    parser.add_argument(
        "--isolate",
        action="store_true",
        help="run each component of this machine alone in a container of its own (untrusted "
        "or crash-prone code: a fault takes down no other component; more processes)",
    )
    parser.add_argument(
        "--workers-as-peers",
        action="store_true",
        help="its worker processes (containers, pool members) join the network as zenoh peers, "
        "each linked to every other process, instead of clients of this host manager with one "
        "link each (the default for a peer without TLS; they fall back to the hub while it is "
        "down)",
    )
    parser.add_argument(
        "--quiet",
        action="store_true",
        help="no status line (every 10 s: workers running, pool ready, requests, the clock's "
        "offset to the agent's)",
    )
    parser.add_argument(
        "--pool-size",
        type=int,
        default=DEFAULT_POOL_SIZE,
        help="idle pre-started workers kept ready to start (or restore) a container at once; "
        "each holds about 100 MB (default: %(default)s)",
    )


def labels(text: str) -> frozenset[str]:
    """The ``--labels`` option: comma-separated labels."""
    try:
        names = parse_labels(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    if len(names) > MAX_LABELS:
        raise argparse.ArgumentTypeError(f"at most {MAX_LABELS} labels")
    return names


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m ubitrack_agent.services.host",
        description="Start, stop and supervise this machine's pattern workers for the agent.",
    )
    add_arguments(parser)
    parser.add_argument(
        "--started-by-agent",
        action="store_true",
        help="standard input is a pipe from the agent that started it: once it closes (the "
        "agent died or stood by), serve on for the agent's successor, and end after "
        f"{ORPHAN_END_S:.0f} s without a component or an active agent",
    )
    logs.add_log_level_argument(parser)
    config.add_arguments(parser)
    return parser


def serve(
    settings: Settings,
    name: str | None,
    pool_size: int,
    started_by_agent: bool = False,
    quiet: bool = False,
    labels: frozenset[str] = frozenset(),
    capacity: int = DEFAULT_CAPACITY,
    cores: int = 1,
    isolate: bool = False,
    workers_as_peers: bool = False,
) -> int:
    """Run a host manager until SIGTERM or SIGINT (started by an agent: also once unneeded
    after the agent is gone); the exit status (2 for invalid options, 3 when another host
    manager of its name came first: ``host_claim.NAME_TAKEN``). ``name`` (default: the
    ``host_name`` setting) is also the host name its workers are started with."""
    if name is None:
        name = settings.host_name
    settings = replace(settings, host_name=name)
    try:
        validate_key_chunks(name, single_chunk=True)
    except ValueError as exc:
        print(f"host: --name: {exc}", file=sys.stderr)
        return 2
    if pool_size < 0:
        print("host: --pool-size must be >= 0", file=sys.stderr)
        return 2
    if not 1 <= capacity <= MAX_CAPACITY:
        print(f"host: --capacity must be 1 to {MAX_CAPACITY}", file=sys.stderr)
        return 2
    if not 1 <= cores <= MAX_CORES:
        print(f"host: --cores must be 1 to {MAX_CORES}", file=sys.stderr)
        return 2
    # Imported here: the registry and zenoh are heavy, and ``ubitrack --help`` reads this module.
    from ubitrack_agent.net.clock import Clock
    from ubitrack_agent.services.host_claim import NAME_TAKEN, HostClaim

    keys = KeySpace(settings.key_prefix)
    steps = [("started", time.monotonic())]
    session, flags = open_host_session(settings, gateway=not workers_as_peers)
    with session:
        steps.append(("session", time.monotonic()))
        claim = HostClaim(session, keys, name)
        from ubitrack_agent.services.host_manager import (
            HostManager,  # heavy: the registry, every service
        )

        steps.append(("imports", time.monotonic()))
        rival = claim.settle()
        if rival is not None:
            write_line(f"host {name}: {rival}: exiting", sys.stderr)
            return NAME_TAKEN
        steps.append(("settled", time.monotonic()))
        info = HostInfo(name, labels, capacity, cores=cores, isolating=isolate)
        manager = HostManager(session, keys, info, flags, pool_size, Clock.of(settings))
        steps.append(("services", time.monotonic()))
        manager.counters.update(claim.counters)
        on_termination(manager.stop)
        if started_by_agent:
            threading.Thread(target=_orphan_when_stdin_closes, args=(manager,), daemon=True).start()
        took = ", ".join(f"{b[0]} {b[1] - a[1]:.1f} s" for a, b in itertools.pairwise(steps))
        write_line(f"host {name}: serving {keys.host_request(name)} ({took})")
        with periodic_status(lambda: status_line(manager.status()), not quiet):
            manager.run()
    return 0


def gateway_possible(settings: Settings) -> bool:
    """Whether this host manager can be its workers' gateway (their zenoh router): as a peer
    without TLS. A client of a site's router, or a TLS network, keeps the workers as
    :func:`ubitrack_agent.net.config.member_of` makes them (a client is one link anyway)."""
    return settings.mode == "peer" and not settings.tls


def free_loopback_port() -> int:
    """A TCP port on loopback that was free a moment ago (where a host manager's worker
    processes connect as its clients)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


GATEWAY_PORT_TRIES = 5
"""Ports tried for the workers' gateway before giving up: a port free a moment ago may be taken
(another process's listener, or an outgoing connection's ephemeral port) before zenoh binds it."""


def open_host_session(settings: Settings, gateway: bool) -> tuple[zenoh.Session, list[str]]:
    """The host manager's session and the flags its workers join with: with ``gateway`` (and
    :func:`gateway_possible`) it also listens on a loopback port its workers connect to as
    clients, trying another port when that one was taken meanwhile (zenoh cannot say which port
    it bound for ``:0``, so the port is chosen here)."""
    import zenoh

    from ubitrack_agent.net.session import open_session

    if not (gateway and gateway_possible(settings)):
        return open_session(settings), config.member_flags(settings)
    for attempt in itertools.count(1):
        endpoint = f"tcp/127.0.0.1:{free_loopback_port()}"
        try:
            session = open_session(replace(settings, listen=(*settings.listen, endpoint)))
        except zenoh.ZError as exc:
            if "Address already in use" in str(exc) and attempt < GATEWAY_PORT_TRIES:
                continue
            raise
        return session, config.as_flags(config.client_of(settings, endpoint))


def status_line(status: dict[str, Any]) -> str:
    """The host manager's one-line status (``net.status_line``)."""
    counters = status["counters"]
    clock = status["clock"]
    offset = (
        "no clock offset to the agent yet"
        if clock is None
        else f"clock {clock['offset_ns'] / 1e6:+.3f} ms to the agent's "
        f"(+-{clock['uncertainty_ns'] / 1e6:.3f})"
    )
    return (
        f"host {status['name']}: {len(status['instances'])} workers running, pool "
        f"{status['pool_ready']} of {status['pool_size']} ready; {counters.get('requests', 0)} "
        f"requests, {counters.get('exits_reported', 0)} workers ended on their own; {offset}"
    )


def _orphan_when_stdin_closes(manager: HostManager) -> None:
    """Tell ``manager`` once standard input closes that the agent that started it is gone."""
    while os.read(sys.stdin.fileno(), 4096):  # no buffered reader: its lock would hold up exit
        pass
    manager.orphan()


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logs.configure(args.log_level)
    try:
        settings = config.from_arguments(args, role="member")
    except config.ConfigError as exc:
        print(f"host: {exc}", file=sys.stderr)
        return 2
    return serve(
        settings,
        args.name,
        args.pool_size,
        args.started_by_agent,
        args.quiet,
        args.labels,
        args.capacity,
        args.cores,
        args.isolate,
        args.workers_as_peers,
    )


def exit_at_once(status: int) -> NoReturn:
    """End the process with ``status`` once :func:`serve` has returned (every declaration
    undeclared, the session closed, every worker ended), flushing the output and the logs but
    skipping the interpreter's teardown of the modules: with numpy, scipy and OpenCV loaded it
    took 0.7-3.8 s at a load of 7-10 on two cores (more under a test suite's load), which the
    agent's clean stop waited for (``ubitrack agent --stop-host-on-exit``)."""
    sys.stdout.flush()
    sys.stderr.flush()
    logging.shutdown()
    os._exit(status)


if __name__ == "__main__":
    exit_at_once(main())
