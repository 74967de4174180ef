"""The application of ``bench.hosts_bench``, run inside a machine's network namespace: asks for
a relation as an application on that machine and prints, one JSON line each,

* ``{"sample": <timestamp ns>, "arrival": <ns>}`` for every sample of the relation;
* ``{"host": "<name>", "kind": "PUT"|"DELETE", "at": <ns>}`` for every host manager token event.

Times are ``time.time_ns()``: every namespace shares the kernel's clock, so the bench compares
them with its own. Run ``python -m bench.hosts_observer FROM TO TYPE [zenoh flags]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time

from ubitrack_agent.io.application import Relation
from ubitrack_agent.net import config
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.session import open_session

_print_lock = threading.Lock()


def say(document: dict) -> None:
    with _print_lock:
        print(json.dumps(document), flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.hosts_observer")
    parser.add_argument("source")
    parser.add_argument("target")
    parser.add_argument("type")
    config.add_arguments(parser)
    args = parser.parse_args()
    settings = config.from_arguments(args, role="member")
    keys = KeySpace(settings.key_prefix)
    relation = RelationId(args.source, args.target, args.type)

    def on_host(sample) -> None:
        name = keys.parse_host(str(sample.key_expr))
        kind = "PUT" if str(sample.kind) == "SampleKind.PUT" else "DELETE"
        say({"host": name, "kind": kind, "at": time.time_ns()})

    with (
        open_session(settings) as session,
        session.liveliness().declare_subscriber(keys.all_hosts(), on_host),
        Relation(
            session,
            keys,
            relation,
            application="bench",
            host=settings.host_name,
            callback=lambda m: say({"sample": m.timestamp_ns, "arrival": time.time_ns()}),
        ),
    ):
        threading.Event().wait()  # until the bench ends the process
    return 0


if __name__ == "__main__":
    sys.exit(main())
