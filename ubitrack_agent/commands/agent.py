"""``ubitrack agent``: run the live agent (the zenoh hub of the embedded default), with a host
manager for its own machine as a child process unless ``--no-host``; that host manager takes
the capacity options of ``ubitrack host`` (``--pool-size``, ``--labels``, ``--capacity``,
``--cores``, ``--isolate``, ``--workers-as-peers``). A host manager of its machine that runs
already (an earlier agent's, which outlives it, or one run on its own) is adopted instead of
starting another.

Stopping the agent, cleanly (SIGTERM, Ctrl-C) or not (SIGKILL, a crash), stops no data: its
workers keep running and its host manager serves on (it outlives the agent, and ends once it
has run no component and seen no active agent for 30 s), so the agent started again adopts
both and the applications see no gap (``docs/architecture.md``). ``--stop-host-on-exit`` makes
a clean stop end everything instead: every worker the agent runs is stopped and its own host
manager ended (``ubitrack demo`` stops its agent so)."""

from __future__ import annotations

import argparse
import logging
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ubitrack_agent.agent.spares import MAX_REPLICAS, Redundancy
from ubitrack_agent.core.interpreter import module_command
from ubitrack_agent.net import config
from ubitrack_agent.net.host_protocol import DEFAULT_CAPACITY, MAX_CAPACITY, MAX_CORES
from ubitrack_agent.net.lifecycle import on_termination
from ubitrack_agent.net.status_line import periodic_status
from ubitrack_agent.services.host import DEFAULT_POOL_SIZE, labels
from ubitrack_agent.services.host_claim import NAME_TAKEN

log = logging.getLogger("ubitrack.agent")

HOST_EXIT_S = 10.0
"""How long the host manager may take to end its workers (it kills them after its own grace
period) before it is killed itself."""
HOST_RESTART_S = 1.0
"""Pause before starting the host manager again when it ended on its own."""
HOST_CHECK_S = 1.0
"""How often the active agent asks whether its machine's host manager serves (an adopted one
may end: then it starts its own)."""
INVALID_OPTIONS = 2
"""Exit status of a host manager given invalid options (it is not started again)."""


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "agent",
        help="run the agent: watch providers and queries, plan, start and rewire workers",
        description="Watch providers and application queries on zenoh, plan every queried "
        "relation with the pattern templates, and have host managers start, stop and rewire "
        "pattern workers so that each relation flows on its stable key. Starts a host manager "
        "for this machine (python -m ubitrack_agent.services.host) unless --no-host. One agent of "
        "a domain is active; another one started on the domain (on its own endpoint) stands by, "
        "changing nothing and starting no host manager, and takes over, adopting every worker, "
        "when the active one ends. Ends on SIGTERM or Ctrl-C leaving its workers running and "
        "its host manager serving (the agent started again adopts them: the applications' data "
        "goes on), unless --stop-host-on-exit.",
    )
    parser.add_argument(
        "--templates", metavar="DIR", help="template directory (default: the shipped templates/)"
    )
    parser.add_argument(
        "--pool-size",
        type=int,
        default=DEFAULT_POOL_SIZE,
        help="idle pre-started workers the host manager keeps ready for fast reconfiguration; "
        "each holds about 100 MB (default: %(default)s)",
    )
    parser.add_argument(
        "--labels",
        type=labels,
        default=frozenset(),
        help="comma-separated labels of this machine that templates may require, such as "
        "camera,gpu,hmd, for its host manager (as `ubitrack host --labels`; default: none)",
    )
    parser.add_argument(
        "--capacity",
        type=int,
        default=DEFAULT_CAPACITY,
        help="components this machine's host manager runs at most; further starts go to other "
        f"hosts (as `ubitrack host --capacity`; default: %(default)s, 1 to {MAX_CAPACITY})",
    )
    parser.add_argument(
        "--cores",
        type=int,
        help="containers its host manager runs this machine's components in, one process each "
        "(as `ubitrack host --cores`; default: the machine's CPU cores, at most "
        f"{MAX_CORES})",
    )
    parser.add_argument(
        "--isolate",
        action="store_true",
        help="its host manager runs each component alone in a container of its own (as "
        "`ubitrack host --isolate`)",
    )
    parser.add_argument(
        "--workers-as-peers",
        action="store_true",
        help="its host manager's worker processes join the network as zenoh peers, each linked "
        "to every other process, instead of clients of the host manager (as `ubitrack host "
        "--workers-as-peers`)",
    )
    parser.add_argument(
        "--quiet",
        action="store_true",
        help="no status line (every 10 s: role, queries, workers alive, reconfigurations, the "
        "kinds of problem seen)",
    )
    parser.add_argument(
        "--no-spares",
        action="store_true",
        help="run no spare derivations: by default, where the best derivation of a relation "
        "without one of its sensors reads a sensor it leaves out (a third tracker), that "
        "derivation runs beside it and takes the relation over within a sample of the sensor's "
        "loss, at the CPU of its components",
    )
    parser.add_argument(
        "--replicas",
        type=int,
        default=0,
        metavar="N",
        help=f"run N copies (0 to {MAX_REPLICAS}) of each relation's derivation beside it, in "
        "other containers: when the process running the derivation dies, a copy, its filters "
        "warm, takes the relation over within a sample, at N times the derivation's CPU "
        "(default: %(default)s)",
    )
    parser.add_argument(
        "--no-host",
        action="store_true",
        help="start no host manager: workers run where `ubitrack host` runs",
    )
    parser.add_argument(
        "--stop-host-on-exit",
        action="store_true",
        help="on SIGTERM or Ctrl-C, stop every worker this agent runs and end its own host "
        "manager (default: leave both running for the agent started again to adopt, so a "
        "restart interrupts no data; a host manager left so ends once it has run no "
        "component and seen no active agent for 30 s, and with its components after 5 "
        "minutes without an active agent)",
    )
    config.add_arguments(parser)
    parser.set_defaults(func=run)


@dataclass(frozen=True)
class HostOptions:
    """The capacity options of the agent's own host manager (those of ``ubitrack host``)."""

    pool_size: int = DEFAULT_POOL_SIZE
    labels: frozenset[str] = frozenset()
    capacity: int = DEFAULT_CAPACITY
    workers_as_peers: bool = False
    cores: int | None = None
    """``None``: the host manager's default, the machine's CPU cores."""
    isolate: bool = False

    @classmethod
    def of(cls, args: argparse.Namespace) -> HostOptions:
        """The options given to ``ubitrack agent``."""
        return cls(
            args.pool_size,
            args.labels,
            args.capacity,
            args.workers_as_peers,
            args.cores,
            args.isolate,
        )

    def flags(self) -> list[str]:
        """The host manager's command-line flags for these options."""
        flags = ["--pool-size", str(self.pool_size), "--capacity", str(self.capacity)]
        flags += ["--workers-as-peers"] if self.workers_as_peers else []
        flags += ["--cores", str(self.cores)] if self.cores is not None else []
        flags += ["--isolate"] if self.isolate else []
        return [*flags, "--labels", ",".join(sorted(self.labels))] if self.labels else flags

    def problem(self) -> str | None:
        """Why these options are invalid, or ``None``."""
        if self.pool_size < 0:
            return "--pool-size must be >= 0"
        if not 1 <= self.capacity <= MAX_CAPACITY:
            return f"--capacity must be 1 to {MAX_CAPACITY}"
        if self.cores is not None and not 1 <= self.cores <= MAX_CORES:
            return f"--cores must be 1 to {MAX_CORES}"
        return None


class EmbeddedHost:
    """The host manager for this machine (``python -m ubitrack_agent.services.host``), joined to the
    agent's network, started again if it ends while the agent runs. Its standard input is a pipe
    from this process: when the agent dies (or stands by) the host manager serves on, with its
    workers and warm pool, for the agent's successor to adopt (``ubitrack_agent.services.host``,
    ``--started-by-agent``)."""

    def __init__(self, settings: config.Settings, options: HostOptions, log_level: str) -> None:
        self._command = module_command(
            "ubitrack_agent.services.host",
            "--started-by-agent",
            "--quiet",  # the agent's status line counts its workers
            *options.flags(),
            *("--log-level", log_level),
            *config.member_flags(settings),
        )
        self._lock = threading.Lock()
        self._stopping = threading.Event()
        self.gave_way = False
        """Whether it exited because another host manager of its name came first (it is
        not started again: the agent adopts that one)."""
        self.process = self._start()
        threading.Thread(target=self._restart_when_ended, daemon=True).start()

    def _start(self) -> subprocess.Popen:
        return subprocess.Popen(
            self._command, stdin=subprocess.PIPE, env=config.child_environment()
        )

    def _restart_when_ended(self) -> None:
        while True:
            returncode = self.process.wait()
            if returncode == INVALID_OPTIONS:
                log.error("host manager refused its options: no workers can start")
                return
            if returncode == NAME_TAKEN:
                log.info("another host manager of this machine's name came first: using it")
                self.gave_way = True
                return
            if self._stopping.wait(HOST_RESTART_S):
                return
            with self._lock:
                if self._stopping.is_set():
                    return
                log.error("host manager ended with %s: starting it again", returncode)
                self.process = self._start()

    def stop_restarting(self) -> None:
        """The agent is stopping: the host manager is not started again if it ends (safe in a
        signal handler: takes no lock)."""
        self._stopping.set()

    def abandon(self) -> None:
        """Leave the host manager as if the agent had died (its standard input closes): it
        serves on for the agent's successor, and ends once unneeded."""
        with self._lock:  # no start is under way, and none follows
            self._stopping.set()
            self.process.stdin.close()

    def stop(self) -> None:
        """End the host manager, which ends every worker it started."""
        with self._lock:
            self._stopping.set()
            process = self.process
        process.terminate()
        try:
            process.wait(timeout=HOST_EXIT_S)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def status_line(status: dict[str, Any]) -> str:
    """The agent's one-line status (``net.status_line``) from its status."""
    if not status:
        return "agent: starting"
    counters = status["counters"]
    components = status["components"].values()
    problems = sorted(status.get("problems", {}))
    seen = f"; problems: {', '.join(problems)} (ubitrack status)" if problems else ""
    return (
        f"agent {status['agent']['id']} {status['agent']['role']}: "
        f"{len(status['queries'])} queries, {len(status['unsolved'])} unsolved; "
        f"{sum(c['alive'] for c in components)} of {len(components)} workers alive; "
        f"{len(status['providers'])} providers, {len(status['stale_edges'])} stale edges; "
        f"{counters.get('reconfigurations', 0)} reconfigurations, "
        f"{counters.get('restarts', 0)} restarts{seen}"
    )


class HostWhileActive:
    """The agent's :class:`EmbeddedHost`, run while the agent is the active one of its domain
    (``agent.election``) and no host manager of its machine's name serves already (``serving``:
    an earlier agent's, which outlives it, is adopted with its workers and warm pool; asked
    again every ``HOST_CHECK_S``). A standby's host manager would answer the active agent's
    requests under the same host name; stepping down leaves it (it serves on for the agent
    that takes over)."""

    def __init__(self, settings: config.Settings, options: HostOptions, log_level: str) -> None:
        self._options = (settings, options, log_level)
        self._stopping = False
        self._active = False
        self._adopted = False
        self._lock = threading.Lock()
        self.serving: Callable[[], bool] = lambda: False
        """Whether a host manager of this machine's name serves (set once the agent runs)."""
        self.host: EmbeddedHost | None = None
        threading.Thread(target=self._keep_one, daemon=True).start()

    def on_role(self, active: bool) -> None:
        with self._lock:
            self._active = active
            if active:
                self._start_unless_served()
            elif self.host is not None:
                self.host.abandon()
                self.host = None

    def _keep_one(self) -> None:
        while not self._stopping:
            time.sleep(HOST_CHECK_S)
            with self._lock:
                if self._active:
                    self._start_unless_served()

    def _start_unless_served(self) -> None:
        """Start the host manager if none serves this machine's name (under the lock)."""
        if self.host is not None and self.host.gave_way:
            self.host = None
        if self.host is not None or self._stopping:
            return
        if self.serving():
            if not self._adopted:
                log.info("the host manager of this machine runs already: using it")
                self._adopted = True
            return
        self._adopted = False
        self.host = EmbeddedHost(*self._options)

    def stop_restarting(self) -> None:
        """Safe in a signal handler (see :meth:`EmbeddedHost.stop_restarting`)."""
        self._stopping = True
        if self.host is not None:
            self.host.stop_restarting()

    def end(self, keep_workers: bool) -> None:
        """End the host manager, or with ``keep_workers`` leave it serving them. An adopted one
        is left: the agent stopped its components, and it ends once unneeded."""
        with self._lock:
            if self.host is not None:
                self.host.abandon() if keep_workers else self.host.stop()


def run(args: argparse.Namespace) -> int:
    import zenoh

    from ubitrack_agent.agent.runtime import Agent
    from ubitrack_agent.graph.templates import TemplateError, load_templates

    try:
        settings = config.from_arguments(args, role="hub")
        templates = load_templates(args.templates)
    except (config.ConfigError, TemplateError) as exc:
        print(f"ubitrack agent: {exc}", file=sys.stderr)
        return 2
    options = HostOptions.of(args)
    if (problem := options.problem()) is not None:
        print(f"ubitrack agent: {problem}", file=sys.stderr)
        return 2
    try:
        redundancy = Redundancy(spares=not args.no_spares, replicas=args.replicas)
    except ValueError as exc:
        print(f"ubitrack agent: --{exc}", file=sys.stderr)
        return 2
    host = None if args.no_host else HostWhileActive(settings, options, args.log_level)
    try:
        agent = Agent(
            settings, templates, on_role=host.on_role if host else None, redundancy=redundancy
        )
    except zenoh.ZError as exc:
        print(f"ubitrack agent: cannot open zenoh on {settings.listen}: {exc}", file=sys.stderr)
        return 2
    if host is not None:
        host.serving = lambda: settings.host_name in agent.hosts.live

    def stop() -> None:
        if host is not None:
            host.stop_restarting()
        agent.stop(keep_workers=not args.stop_host_on_exit)

    on_termination(stop)
    listening = f"on {', '.join(settings.listen)}" if settings.listen else ""
    where = listening or f"as a client of {', '.join(settings.connect)}"
    print(
        f"ubitrack agent: agent {agent.id} of {agent.keys.root} {where} "
        "(active unless another agent of the domain is)",
        flush=True,
    )
    try:
        with periodic_status(lambda: status_line(agent.latest_status()), not args.quiet):
            agent.run()
    except Exception:
        log.exception("the agent failed; its workers keep running for a restarted agent")
        if host is not None:
            host.end(keep_workers=True)
        return 1
    if host is not None:
        host.end(keep_workers=agent.handed_over or not args.stop_host_on_exit)
    return 0
