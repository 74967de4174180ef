"""``ubitrack subscribe``: ask for a relationship and print each sample as one JSON line."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

from ubitrack_agent.core.lines import write_line
from ubitrack_agent.core.names import parse_labels
from ubitrack_agent.net import config

DEFAULT_TIMEOUT_S = 10.0
"""Seconds ``subscribe`` waits for a sample: a flow starts within about a second once its
sensors are there (docs/performance.md), so ten seconds of silence means something is wrong."""


def no_agent(network: str, timeout: float | None, waited: bool) -> str:
    """What ``subscribe`` and ``calibrate`` say when no agent answered on ``network``
    (``io.waiting.network_of``), at once (``timeout`` None) or at their time-out."""
    from ubitrack_agent.io.application import NO_AGENT_AFTER_S

    seconds = NO_AGENT_AFTER_S if timeout is None else timeout
    wait = "" if waited else "; --wait waits for one"
    return (
        f"no agent on {network} within {seconds:g} s (start `ubitrack agent`, or give the "
        f"--connect and --domain it uses{wait})"
    )


def labels(text: str) -> frozenset[str]:
    """``--host-labels``: comma-separated labels."""
    try:
        return parse_labels(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def relation_types() -> list[str]:
    """The types a relation can be asked for: those a measurement is delivered as (the SRG's
    edge types, ``graph.srg.EDGE_TYPES``, without importing the graph layer's networkx: a
    command that exits at once should not spend a sixth of its time on imports it does not
    use)."""
    from ubitrack_agent.core import MEASUREMENT_TYPES

    return sorted({cls.SRG_TYPE for cls in MEASUREMENT_TYPES.values()})


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "subscribe",
        help="ask the agent for a relationship and print its samples as JSON lines",
        description="Announce a query for FROM->TO and print every sample delivered on its "
        "relation key as one JSON object (type, timestamp_ns, value fields, covariance if any) "
        "until interrupted, --count samples, or --timeout seconds without a sample. The agent's "
        "answer comes at once: if it cannot serve the relation (unknown frame, no "
        "derivation...), its reason and exit 1, with a 'did you mean' for a frame named almost "
        "like an announced one; if it starts a flow for it, a line on stderr as the flow comes "
        "up ('planned: 3 components, 1 alive'), then the samples; if no agent is there within "
        "1.5 s, 'no agent on ENDPOINT/DOMAIN' and exit 1. --wait waits on instead, for sensors "
        "or an agent still starting.",
    )
    parser.add_argument("source", metavar="FROM", help="source frame, e.g. C")
    parser.add_argument("target", metavar="TO", help="target frame, e.g. A")
    parser.add_argument("--type", default="6D", help="relation type (default: %(default)s)")
    parser.add_argument("--static", action="store_true", help="ask for a static relation")
    parser.add_argument("--count", type=int, help="stop after this many samples")
    parser.add_argument(
        "--timeout",
        type=float,
        default=DEFAULT_TIMEOUT_S,
        help="give up (exit 1, saying why) after this many seconds without a sample "
        "(default: %(default)s; inf waits for ever; a static relation still being calibrated "
        "has no sample until it converges: `ubitrack calibrate` shows its progress)",
    )
    parser.add_argument(
        "--wait",
        action="store_true",
        help="keep waiting (up to --timeout) when the agent cannot serve the relation yet or "
        "no agent is there yet, instead of exiting 1 at once",
    )
    parser.add_argument("--app-id", help="application id in the query key (default: generated)")
    parser.add_argument(
        "--host-labels",
        type=labels,
        default=frozenset(),
        metavar="L1,L2",
        help="labels the host computing the relation's last hop must have (ubitrack host "
        "--labels), e.g. display (default: any host)",
    )
    config.add_arguments(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ubitrack_agent.core import to_json
    from ubitrack_agent.io.application import NoAgent, Relation
    from ubitrack_agent.io.waiting import StartWatch, network_of
    from ubitrack_agent.net.keys import KeySpace, RelationId
    from ubitrack_agent.net.session import open_session

    try:
        if args.type not in (types := relation_types()):
            raise ValueError(f"--type: unknown type {args.type!r}, expected {types}")
        if not args.timeout > 0:
            raise ValueError("--timeout must be positive (inf waits for ever)")
        settings = config.from_arguments(args, role="member")
        relation_id = RelationId(args.source, args.target, args.type, args.static)
    except ValueError as exc:
        print(f"ubitrack subscribe: {exc}", file=sys.stderr)
        return 2
    if args.count is not None and args.count < 1:
        print("ubitrack subscribe: --count must be at least 1", file=sys.stderr)
        return 2
    keys = KeySpace(settings.key_prefix)

    def say(line: str) -> None:
        write_line(f"ubitrack subscribe: {relation_id}: {line}", sys.stderr)

    with (
        open_session(settings) as session,
        StartWatch(session, keys, relation_id, say) as watch,
        Relation(
            session,
            keys,
            relation_id,
            args.app_id,
            host=settings.host_name,
            host_labels=args.host_labels,
            keep_waiting=args.wait,
        ) as relation,
    ):
        printed = 0
        try:
            while args.count is None or printed < args.count:
                sample = relation.get(timeout=None if math.isinf(args.timeout) else args.timeout)
                watch.close()  # the flow is up
                latency_ms = (time.time_ns() - sample.timestamp_ns) / 1e6
                line = {**to_json(sample), "latency_ms": round(latency_ms, 3)}
                write_line(json.dumps(line))
                printed += 1
        except NoAgent as exc:
            say(no_agent(network_of(settings), exc.timeout, args.wait))
            return 1
        except TimeoutError as exc:  # UnsolvedRelation with the agent's reason and hint too
            print(f"ubitrack subscribe: {exc}", file=sys.stderr)
            return 1
    return 0
