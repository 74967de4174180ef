"""``ubitrack sim world|art|camera|database``: the simulators, one process each.

Each reads a scenario (``--scenario FILE``, default: the paper's figure-1 setup, see
``docs/simulators.md``) and runs until SIGINT/SIGTERM or ``--duration`` seconds, then closes
its zenoh session or socket and exits 0. A bad scenario or option exits 2 with the reason.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections import Counter
from collections.abc import Callable
from typing import Any

from ubitrack_agent.net import config
from ubitrack_agent.net.status_line import Rate, periodic_status

log = logging.getLogger("ubitrack.sim")


def add_common_arguments(parser: argparse.ArgumentParser, zenoh: bool = True) -> None:
    """``--scenario`` and ``--duration`` (and the zenoh flags if the process uses zenoh)."""
    parser.add_argument(
        "--scenario", help="scenario YAML file (default: the paper's figure-1 setup)"
    )
    parser.add_argument(
        "--duration", type=float, help="stop after this many seconds (default: run until stopped)"
    )
    parser.add_argument("--quiet", action="store_true", help="no status line (every 10 s)")
    if zenoh:
        config.add_arguments(parser)


def load(args: argparse.Namespace, prog: str) -> Any:
    """The scenario named by ``--scenario``; ``None`` after printing why it is invalid."""
    from ubitrack_agent.sim_trackers.scenario import ScenarioError, load_scenario

    try:
        return load_scenario(args.scenario)
    except ScenarioError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return None


def prepare(args: argparse.Namespace, prog: str) -> tuple[Any, config.Settings] | None:
    """The scenario and the zenoh settings of a member process; ``None`` after printing why
    either is invalid."""
    scenario = load(args, prog)
    try:
        settings = config.from_arguments(args, role="member")
    except config.ConfigError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return None
    return None if scenario is None else (scenario, settings)


def _rate(value: float | None, default: float, prog: str) -> float | None:
    rate = default if value is None else value
    if not 0.0 < rate <= 10_000.0:
        print(f"{prog}: --rate must be in (0, 10000] Hz, got {rate}", file=sys.stderr)
        return None
    return rate


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "sim",
        help="run a simulator: world (ground truth), art (DTrack UDP), camera, database",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    commands = parser.add_subparsers(dest="simulator", required=True, metavar="SIMULATOR")
    _add(commands, "world", _run_world, "serve the ground truth on <root>/truth/<from>/<to>")
    art = _add(
        commands, "art", _run_art, "send A.R.T. DTrack2 ASCII datagrams over UDP", zenoh=False
    )
    art.add_argument("--host", default="127.0.0.1", help="destination (default: %(default)s)")
    art.add_argument("--port", type=int, help="destination UDP port (default: scenario art.port)")
    art.add_argument("--rate", type=float, help="frames per second (default: scenario art.rate)")
    art.add_argument("--seed", type=int, help="noise seed (default: scenario seed)")
    art.add_argument(
        "--clock-offset-ms",
        metavar="MS",
        default=0.0,
        help="for tests: the simulated controller's clock (its ts lines) reads this much ahead "
        "(a host whose clock is off; give its DTrack adapter the same; default: 0)",
    )
    camera = _add(commands, "camera", _run_camera, "publish 2D marker features (IP->Fi)")
    camera.add_argument("--rate", type=float, help="frames per second (default: scenario)")
    camera.add_argument("--seed", type=int, help="noise seed (default: scenario seed)")
    database = _add(commands, "database", _run_database, "serve the static calibration edges")
    database.add_argument(
        "--edges",
        metavar="FILE",
        help="serve this static-edges file (ubitrack_agent/io/static_edges.py) instead of the "
        "scenario's truth",
    )
    database.add_argument(
        "--dump",
        metavar="FILE",
        help="write the edges it would serve to this static-edges file (atomically) and exit",
    )


def _add(
    commands: argparse._SubParsersAction,
    name: str,
    run: Callable[[argparse.Namespace], int],
    summary: str,
    zenoh: bool = True,
) -> argparse.ArgumentParser:
    parser = commands.add_parser(name, help=summary, description=f"{summary}.")
    add_common_arguments(parser, zenoh)
    parser.set_defaults(func=run)
    return parser


def _run_world(args: argparse.Namespace) -> int:
    from ubitrack_agent.net.keys import KeySpace
    from ubitrack_agent.net.lifecycle import stop_on_signals
    from ubitrack_agent.net.session import open_session
    from ubitrack_agent.sim_trackers.truth import TruthServer

    prog = "ubitrack sim world"
    if (prepared := prepare(args, prog)) is None:
        return 2
    scenario, settings = prepared
    stop = stop_on_signals()
    with open_session(settings) as session:
        server = TruthServer(session, KeySpace(settings.key_prefix), scenario.world)

        def line() -> str:
            return f"sim world: {server.answered} truth queries answered, {server.failed} failed"

        try:
            with periodic_status(line, not args.quiet):
                stop.wait(args.duration)
        finally:
            server.close()
    log.info("answered %d truth queries, %d failed", server.answered, server.failed)
    return 0


def _run_art(args: argparse.Namespace) -> int:
    import numpy as np

    from ubitrack_agent.net.clock import Clock
    from ubitrack_agent.net.lifecycle import stop_on_signals
    from ubitrack_agent.sim_trackers import sim_art

    prog = "ubitrack sim art"
    scenario = load(args, prog)
    if scenario is None:
        return 2
    if (rate := _rate(args.rate, scenario.art.rate, prog)) is None:
        return 2
    port = scenario.art.port if args.port is None else args.port
    seed = scenario.seed if args.seed is None else args.seed
    try:
        offset_ms = config.parse_clock_offset("--clock-offset-ms", args.clock_offset_ms)
    except config.ConfigError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    simulator = sim_art.ArtSimulator(
        scenario.world,
        scenario.art,
        np.random.default_rng(seed),
        Clock(round(offset_ms * 1e6)),
    )
    counters: Counter[str] = Counter()
    sent = Rate(lambda: counters["sent"])

    def line() -> str:
        return (
            f"sim art: {sent.per_second():.1f} datagrams/s to {args.host}:{port}, "
            f"{counters['send_failed']} sends failed"
        )

    try:
        with periodic_status(line, not args.quiet):
            sim_art.run(
                simulator, (args.host, port), rate, stop_on_signals(), args.duration, counters
            )
    except OSError as exc:
        print(f"{prog}: cannot send to {args.host}:{port}: {exc}", file=sys.stderr)
        return 2
    return 0


def _run_camera(args: argparse.Namespace) -> int:
    import numpy as np

    from ubitrack_agent.net.clock import Clock
    from ubitrack_agent.net.lifecycle import stop_on_signals
    from ubitrack_agent.sim_trackers.runtime import provider_session, run_periodic
    from ubitrack_agent.sim_trackers.sim_camera import CameraSimulator, announcements

    prog = "ubitrack sim camera"
    if (prepared := prepare(args, prog)) is None:
        return 2
    scenario, settings = prepared
    if (rate := _rate(args.rate, scenario.camera.rate, prog)) is None:
        return 2
    seed = scenario.seed + 1 if args.seed is None else args.seed
    simulator = CameraSimulator(
        scenario.world, scenario.camera, np.random.default_rng(seed), Clock.of(settings)
    )
    stop = stop_on_signals()
    edges = announcements(scenario.camera, scenario.world)
    with provider_session(settings, scenario.camera.provider, edges) as provider:
        counters: Counter[str] = Counter()
        published = Rate(lambda: counters["frames"])

        def publish(now_ns: int) -> None:
            measurements = simulator.measure(now_ns)
            for edge, measurement in measurements.items():
                provider.publish(edge, measurement)
            counters["frames"] += 1
            counters["features"] += len(measurements)

        def line() -> str:
            return (
                f"sim camera: {published.per_second():.1f} frames/s, {counters['features']} "
                f"features in {counters['frames']} frames"
            )

        with periodic_status(line, not args.quiet):
            frames = run_periodic(rate, publish, stop, args.duration)
    log.info("published %d camera frames", frames)
    return 0


def _run_database(args: argparse.Namespace) -> int:
    import time

    from ubitrack_agent.io.static_edges import (
        StaticEdgesError,
        read_static_edges,
        write_static_edges,
    )
    from ubitrack_agent.net.lifecycle import stop_on_signals
    from ubitrack_agent.sim_trackers.database import static_edges
    from ubitrack_agent.sim_trackers.runtime import provider_session

    prog = "ubitrack sim database"
    if (prepared := prepare(args, prog)) is None:
        return 2
    scenario, settings = prepared
    if args.edges is None:
        provider_id = scenario.database_provider
        edges = static_edges(scenario.world, scenario.database_edges, time.time_ns())
    else:
        try:
            provider_id, edges = read_static_edges(args.edges, time.time_ns())
        except StaticEdgesError as exc:
            print(f"{prog}: {exc}", file=sys.stderr)
            return 2
    if args.dump is not None:
        try:
            write_static_edges(args.dump, provider_id, edges)
        except OSError as exc:
            print(f"{prog}: cannot write {args.dump}: {exc}", file=sys.stderr)
            return 2
        return 0
    stop = stop_on_signals()
    announced = [edge.served_announcement() for edge in edges]
    with provider_session(settings, provider_id, announced) as provider:
        for edge in edges:
            provider.publish(edge.announcement.name, edge.value)
        line = f"sim database: serving {len(edges)} static edges as provider {provider_id}"
        with periodic_status(lambda: line, not args.quiet):
            stop.wait(args.duration)
    return 0
