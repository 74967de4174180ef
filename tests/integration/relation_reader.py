"""An application in a process of its own reading one relation (``io.application.Relation``),
which a test can stop (SIGSTOP) and resume: a reader outside the middleware's control.

Run ``python -m tests.integration.relation_reader --frames FROM TO TYPE [zenoh flags]``; it
prints ``{"ready": true}`` once subscribed, then answers each line of input with one JSON line:
the samples it received, the newest one's timestamp and the samples it counted ``missed``.
"""

from __future__ import annotations

import argparse
import json
import sys

from ubitrack_agent.io.application import Relation
from ubitrack_agent.net import config
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.session import open_session


def main() -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.integration.relation_reader")
    parser.add_argument("--frames", nargs=3, required=True, metavar=("FROM", "TO", "TYPE"))
    config.add_arguments(parser)
    args = parser.parse_args()
    settings = config.from_arguments(args, role="member")
    with (
        open_session(settings) as session,
        Relation(session, KeySpace(settings.key_prefix), RelationId(*args.frames)) as relation,
    ):
        print(json.dumps({"ready": True}), flush=True)
        for _ in sys.stdin:
            latest = relation.latest()
            answer = {
                "received": relation.received,
                "newest": None if latest is None else latest.timestamp_ns,
                "missed": relation.counters["missed"],
            }
            print(json.dumps(answer), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
