"""``ubitrack subscribe``: ask for a relationship and print each sample as one JSON line."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

from ubitrack_agent.core.names import parse_labels
from ubitrack_agent.net import config

DEFAULT_TIMEOUT_S = 10.0
"""Seconds ``subscribe`` waits for a sample: a flow starts within about a second once its
sensors are there (docs/performance.md), so ten seconds of silence means something is wrong."""


def labels(text: str) -> frozenset[str]:
    """``--host-labels``: comma-separated labels."""
    try:
        return parse_labels(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "subscribe",
        help="ask the agent for a relationship and print its samples as JSON lines",
        description="Announce a query for FROM->TO and print every sample delivered on its "
        "relation key as one JSON object (type, timestamp_ns, value fields, covariance if any) "
        "until interrupted, --count samples, or --timeout seconds without a sample; then exit 1 "
        "with the agent's reason when it cannot serve the relation (unknown frame, no "
        "derivation...).",
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
    from ubitrack_agent.graph.srg import EDGE_TYPES
    from ubitrack_agent.io.application import Relation
    from ubitrack_agent.net.keys import KeySpace, RelationId
    from ubitrack_agent.net.session import open_session

    try:
        if args.type not in EDGE_TYPES:
            raise ValueError(f"--type: unknown type {args.type!r}, expected {sorted(EDGE_TYPES)}")
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
    with (
        open_session(settings) as session,
        Relation(
            session,
            keys,
            relation_id,
            args.app_id,
            host=settings.host_name,
            host_labels=args.host_labels,
        ) as relation,
    ):
        printed = 0
        try:
            while args.count is None or printed < args.count:
                sample = relation.get(timeout=None if math.isinf(args.timeout) else args.timeout)
                latency_ms = (time.time_ns() - sample.timestamp_ns) / 1e6
                line = {**to_json(sample), "latency_ms": round(latency_ms, 3)}
                print(json.dumps(line), flush=True)
                printed += 1
        except TimeoutError as exc:  # with the agent's reason (UnsolvedRelation, NoAgent)
            print(f"ubitrack subscribe: {exc}", file=sys.stderr)
            return 1
    return 0
