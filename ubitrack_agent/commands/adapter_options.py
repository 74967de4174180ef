"""What the sensor-adapter commands share (``ubitrack dtrack``, ``ubitrack natnet``): the
options naming the provider, the tracker frame, static bodies, the announced rate, the noise,
the timestamp policy and the run's length, and the ``ID=FRAME`` / ``NAME=FRAME`` mappings.
Not a command itself (it defines no ``register``)."""

from __future__ import annotations

import argparse
import logging
import threading
from collections.abc import Callable, Hashable
from typing import Any, TypeVar

Key = TypeVar("Key", bound=Hashable)


def id_frame(text: str) -> tuple[int, str]:
    """``ID=FRAME`` with a non-negative integer id (``argparse`` type)."""
    ident, sep, frame = text.partition("=")
    if not sep or not ident.isdigit() or not frame:
        raise argparse.ArgumentTypeError(f"expected ID=FRAME like 1=HT, got {text!r}")
    return int(ident), frame


def name_frame(text: str) -> tuple[str, str]:
    """``NAME=FRAME`` (``argparse`` type)."""
    name, sep, frame = text.partition("=")
    if not sep or not name or not frame:
        raise argparse.ArgumentTypeError(f"expected NAME=FRAME like HT=HT, got {text!r}")
    return name, frame


def mapping(pairs: list[tuple[Key, str]], option: str) -> dict[Key, str]:
    """``pairs`` as a mapping; ``ValueError`` if a key is given twice."""
    result: dict[Key, str] = {}
    for key, frame in pairs:
        if key in result:
            raise ValueError(f"{option} {key} is given twice ({result[key]}, {frame})")
        result[key] = frame
    return result


def add_adapter_arguments(
    parser: argparse.ArgumentParser,
    *,
    provider: str,
    system: str,
    tracker_frame: str,
    rate: float,
    sigma_mm: float,
    sigma_deg: float,
    device_timestamps: str,
    status: str,
) -> None:
    """``--provider`` (default ``provider``, one per ``system``), ``--tracker-frame``,
    ``--static``, ``--rate``, ``--sigma-mm``, ``--sigma-deg``, ``--timestamps`` (the help of
    ``device`` is ``device_timestamps``), ``--quiet`` (``status``: what the status line says)
    and ``--duration``."""
    parser.add_argument(
        "--provider",
        default=provider,
        help=f"provider id, one per {system} (default: %(default)s)",
    )
    parser.add_argument(
        "--tracker-frame",
        default=tracker_frame,
        help="the tracker's frame, source of every edge (default: %(default)s)",
    )
    parser.add_argument(
        "--static",
        action="append",
        default=[],
        metavar="FRAME",
        help="announce this body's edge as static: fixed in the room (repeatable)",
    )
    parser.add_argument(
        "--rate",
        type=float,
        metavar="HZ",
        default=rate,
        help="announced frame rate in Hz, for the planner (default: %(default)s)",
    )
    parser.add_argument(
        "--sigma-mm",
        type=float,
        metavar="MM",
        default=sigma_mm,
        help="position noise per axis, mm (default: %(default)s)",
    )
    parser.add_argument(
        "--sigma-deg",
        type=float,
        metavar="DEG",
        default=sigma_deg,
        help="rotation noise per axis about the body's origin, degrees (default: %(default)s)",
    )
    parser.add_argument(
        "--timestamps",
        choices=("receive", "device"),
        default="receive",
        help=f"receive: this host's receive time; device: {device_timestamps} "
        "(default: %(default)s)",
    )
    parser.add_argument(
        "--quiet", action="store_true", help=f"no status line (every 10 s: {status})"
    )
    parser.add_argument(
        "--duration",
        type=float,
        metavar="SECONDS",
        help="stop after this many seconds (default: run until stopped)",
    )


def status_line(
    name: str, adapter: Any, unit: str, hint: Callable[[float], str]
) -> Callable[[], str]:
    """The adapter's one-line status (``net.status_line``): inputs (``unit``) and measurements
    per second since the last line, rejections so far, and ``hint(inputs per second)``."""
    from ubitrack_agent.net.status_line import Rate

    received = Rate(lambda: adapter.counters["received"])
    published = Rate(lambda: adapter.counters["published"])

    def line() -> str:
        per_second = received.per_second()
        return (
            f"{name}: {per_second:.1f} {unit}/s, {published.per_second():.1f} measurements/s "
            f"published; {adapter.counters['rejected']} {unit} rejected{hint(per_second)}"
        )

    return line


def serve_adapter(
    name: str,
    settings: Any,
    args: argparse.Namespace,
    adapter: Any,
    serve: Callable[[Any, threading.Event, Any], None],
    status: Callable[[], str],
) -> int:
    """Announce ``adapter``'s edges as provider ``args.provider`` on a zenoh session of
    ``settings``, run ``serve(provider, stop, clock)`` with the status line (unless
    ``args.quiet``) until SIGINT/SIGTERM or its own end, log the counters; returns 0."""
    from ubitrack_agent.io.provider import Provider
    from ubitrack_agent.net.clock import Clock
    from ubitrack_agent.net.keys import KeySpace
    from ubitrack_agent.net.lifecycle import stop_on_signals
    from ubitrack_agent.net.session import open_session
    from ubitrack_agent.net.status_line import periodic_status

    stop = stop_on_signals()
    with (
        open_session(settings) as session,
        Provider(
            session, KeySpace(settings.key_prefix), args.provider, adapter.edges, settings.host_name
        ) as provider,
        periodic_status(status, not args.quiet),
    ):
        provider.leave_on_signals(stop)
        serve(provider, stop, Clock.of(settings))
    logging.getLogger(f"ubitrack.{name}").info("%s counters: %s", name, dict(adapter.counters))
    return 0
