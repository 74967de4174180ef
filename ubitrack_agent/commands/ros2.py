"""``ubitrack ros2``: ROS 2 tf over rmw_zenoh (Jazzy and later), both ways (docs/ros2.md).

``ubitrack ros2 publish C/A --static WT/HT`` asks the agent for the relations C->A (dynamic)
and WT->HT (static) and publishes them as tf2_msgs/msg/TFMessage: dynamic ones on /tf, static
ones on /tf_static (transient-local: the whole static tree in one message, delivered to
subscribers that join later), as a ROS 2 node (liveliness tokens: ``ros2 node list`` shows
it). A relation FROM/TO becomes frame_id FROM, child_frame_id TO; stamps are the measurement
timestamps. SRG frame names map to ROS frame ids with '.' -> '/' (robot1.base -> robot1/base);
a name that is no ROS frame id is refused (exit 2, naming it) unless --frame SRG=ROS maps it.

``ubitrack ros2 subscribe`` reads /tf and /tf_static and announces each parent -> child
transform as a 6D SRG edge (static for /tf_static) under provider PROVIDER, with the noise
given by --sigma-mm/--sigma-deg (tf carries none), so a robot's tf tree and this project's
trackers meet in one SRG. ROS frame ids map to SRG names with '/' -> '.'; refused ids and
malformed samples are counted and logged, never fatal.

Both speak rmw_zenoh's wire format over this process's zenoh session (the --connect/--listen
options below): run ROS 2 with RMW_IMPLEMENTATION=rmw_zenoh_cpp and connect to the same zenoh
router. Needs the ros2 extra: pip install "ubitrack-agent[ros2]". Runs until SIGINT/SIGTERM or
--duration seconds; prints a status line every 10 s unless --quiet.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import threading
from collections.abc import Callable
from typing import Any

from ubitrack_agent.net import config

log = logging.getLogger("ubitrack.ros2")

EXTRA_HINT = 'needs the ros2 extra: pip install "ubitrack-agent[ros2]"'


def _relation(text: str) -> tuple[str, str]:
    source, sep, target = text.partition("/")
    if not sep or not source or not target or "/" in target:
        raise argparse.ArgumentTypeError(f"expected FROM/TO like C/A, got {text!r}")
    return source, target


def _frame(text: str) -> tuple[str, str]:
    srg, sep, ros = text.partition("=")
    if not sep or not srg or not ros:
        raise argparse.ArgumentTypeError(f"expected SRG=ROS like HT=head_target, got {text!r}")
    return srg, ros


def _default_domain_id() -> int:
    text = os.environ.get("ROS_DOMAIN_ID", "").strip()
    return int(text) if text.isdigit() else 0


def _common(parser: argparse.ArgumentParser, node_name: str) -> None:
    parser.add_argument(
        "--ros-domain-id",
        type=int,
        default=_default_domain_id(),
        metavar="ID",
        help="ROS domain id, 0-232 (default: $ROS_DOMAIN_ID or 0: %(default)s)",
    )
    parser.add_argument(
        "--node-name", default=node_name, help="ROS node name (default: %(default)s)"
    )
    parser.add_argument("--namespace", default="/", help="ROS namespace (default: %(default)s)")
    parser.add_argument(
        "--frame",
        type=_frame,
        action="append",
        default=[],
        metavar="SRG=ROS",
        help="name SRG frame SRG as ROS frame id ROS, both ways (repeatable)",
    )
    parser.add_argument(
        "--frame-prefix",
        default="",
        metavar="PREFIX",
        help="SRG names of ROS frames start with PREFIX (e.g. ros.: base_link <-> "
        "ros.base_link; default: none)",
    )
    parser.add_argument("--quiet", action="store_true", help="no status line")
    parser.add_argument(
        "--duration", type=float, metavar="SECONDS", help="stop after this many seconds"
    )
    config.add_arguments(parser)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "ros2",
        help="ROS 2 tf over rmw_zenoh: publish relations, or read a robot's tf tree",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    commands = parser.add_subparsers(dest="ros2_command", required=True, metavar="ACTION")
    publish = commands.add_parser(
        "publish",
        help="publish relations on /tf and /tf_static",
        description="Follow relations FROM/TO and publish them as tf (see ubitrack ros2 -h).",
    )
    publish.add_argument(
        "relations",
        metavar="FROM/TO",
        type=_relation,
        nargs="*",
        help="a dynamic relation to publish on /tf, e.g. C/A",
    )
    publish.add_argument(
        "--static",
        type=_relation,
        action="append",
        default=[],
        metavar="FROM/TO",
        help="a static relation to publish on /tf_static (repeatable)",
    )
    _common(publish, "ubitrack_tf")
    publish.set_defaults(func=run)
    subscribe = commands.add_parser(
        "subscribe",
        help="announce /tf and /tf_static as SRG edges",
        description="Read /tf and /tf_static and announce them as SRG edges (see ubitrack "
        "ros2 -h).",
    )
    subscribe.add_argument(
        "--provider", default="ros2", help="provider id of the edges (default: %(default)s)"
    )
    subscribe.add_argument(
        "--sigma-mm",
        type=float,
        default=1.0,
        metavar="MM",
        help="assumed position noise per axis, mm (default: %(default)s)",
    )
    subscribe.add_argument(
        "--sigma-deg",
        type=float,
        default=0.1,
        metavar="DEG",
        help="assumed rotation noise per axis, degrees (default: %(default)s)",
    )
    subscribe.add_argument(
        "--rate",
        type=float,
        metavar="HZ",
        help="announced rate of dynamic edges, for the planner and the quiet-edge check "
        "(default: none, never quiet)",
    )
    subscribe.add_argument(
        "--timestamps",
        choices=("device", "receive"),
        default="device",
        help="device: the transforms' header stamps (zero: receive time); receive: this "
        "host's receive time (default: %(default)s)",
    )
    _common(subscribe, "ubitrack_tf_listener")
    subscribe.set_defaults(func=run)


Serve = Callable[[Any, Any, threading.Event], None]
"""What a subcommand runs once its options are checked: (session, settings, stop)."""


def run(args: argparse.Namespace) -> int:
    prog = f"ubitrack ros2 {args.ros2_command}"
    try:
        import rosbags  # noqa: F401
    except ImportError:
        print(f"{prog}: {EXTRA_HINT}", file=sys.stderr)
        return 2
    from ubitrack_agent.io.ros2.frames import FrameNames
    from ubitrack_agent.io.ros2.keys import check_domain_id
    from ubitrack_agent.net.lifecycle import stop_on_signals
    from ubitrack_agent.net.session import open_session

    try:
        settings = config.from_arguments(args, role="member")
        check_domain_id(args.ros_domain_id)
        frames = FrameNames(dict(args.frame), args.frame_prefix)
        prepare = _publisher if args.ros2_command == "publish" else _subscriber
        serve = prepare(args, frames)
    except ValueError as exc:  # FrameNameError, config.ConfigError too
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    stop = stop_on_signals()
    with open_session(settings) as session:
        serve(session, settings, stop)
    return 0


def _publisher(args: argparse.Namespace, frames: Any) -> Serve:
    """``publish``: the relations checked (refused frame names raise), then what runs."""
    from ubitrack_agent.io.ros2.publisher import TfPublisher
    from ubitrack_agent.io.ros2.relations import RelationsToTf, ros_frames
    from ubitrack_agent.net.keys import KeySpace, RelationId
    from ubitrack_agent.net.status_line import Rate, periodic_status

    relations = [RelationId(s, t, "6D") for s, t in args.relations] + [
        RelationId(s, t, "6D", static=True) for s, t in args.static
    ]
    if not relations:
        raise ValueError("no relation: give FROM/TO (on /tf) or --static FROM/TO")
    ros_frames(relations, frames)  # every refused name, before anything starts

    def serve(session: Any, settings: Any, stop: threading.Event) -> None:
        with (
            TfPublisher(session, args.ros_domain_id, args.node_name, args.namespace) as publisher,
            RelationsToTf(
                session,
                KeySpace(settings.key_prefix),
                relations,
                publisher,
                frames,
                settings.host_name,
            ) as bridge,
        ):
            rate = Rate(lambda: bridge.counters["dynamic"])

            def line() -> str:
                return (
                    f"ros2 publish: {rate.per_second():.1f} transforms/s on /tf, "
                    f"{len(publisher.static_transforms)} on /tf_static"
                )

            with periodic_status(line, not args.quiet):
                bridge.run(stop, args.duration)
        log.info("ros2 publish counters: %s %s", dict(bridge.counters), dict(publisher.counters))

    return serve


def _subscriber(args: argparse.Namespace, frames: Any) -> Serve:
    """``subscribe``: the adapter built (bad options raise), then what runs."""
    from ubitrack_agent.io.ros2.provider import GrowingProvider, TfAdapter, serve_tf
    from ubitrack_agent.io.ros2.subscriber import TfSubscriber
    from ubitrack_agent.net.clock import Clock
    from ubitrack_agent.net.keys import KeySpace, validate_key_chunks
    from ubitrack_agent.net.status_line import Rate, periodic_status

    validate_key_chunks(args.provider, single_chunk=True)
    adapter = TfAdapter(frames, args.sigma_mm, args.sigma_deg, args.rate, args.timestamps)

    def serve(session: Any, settings: Any, stop: threading.Event) -> None:
        with (
            TfSubscriber(
                session, args.ros_domain_id, args.node_name, args.namespace, Clock.of(settings)
            ) as subscriber,
            GrowingProvider(
                session,
                KeySpace(settings.key_prefix),
                args.provider,
                lambda: adapter.edges,
                settings.host_name,
            ) as provider,
        ):
            received = Rate(lambda: adapter.counters["received"])

            def line() -> str:
                return (
                    f"ros2 subscribe: {received.per_second():.1f} messages/s, "
                    f"{len(adapter.edges)} edges, {adapter.counters['rejected']} rejected"
                )

            with periodic_status(line, not args.quiet):
                serve_tf(subscriber, adapter, provider, stop, args.duration)
        log.info(
            "ros2 subscribe counters: %s %s", dict(adapter.counters), dict(subscriber.counters)
        )

    return serve
