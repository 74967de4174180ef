"""The baseline hop of ``bench.dataflow_bench``: republish every payload from one key on another,
with zenoh-python's own receive loop and nothing else (no decoding, no computation).

Run: ``python -m bench.raw_relay IN_KEY OUT_KEY [zenoh flags]``; ends on SIGTERM.
"""

from __future__ import annotations

import argparse
import threading

import zenoh

from ubitrack_agent.net import config
from ubitrack_agent.net.lifecycle import stop_on_signals
from ubitrack_agent.net.session import open_session


def main() -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.raw_relay")
    parser.add_argument("source")
    parser.add_argument("target")
    config.add_arguments(parser)
    args = parser.parse_args()
    stop = stop_on_signals()
    with open_session(config.from_arguments(args, role="member")) as session:
        publisher = session.declare_publisher(args.target)
        subscriber = session.declare_subscriber(args.source, zenoh.handlers.FifoChannel(4096))

        def relay() -> None:
            for sample in subscriber:  # ends when the subscriber is undeclared
                publisher.put(sample.payload)

        thread = threading.Thread(target=relay, daemon=True)
        thread.start()
        stop.wait()
        subscriber.undeclare()
        thread.join(timeout=1.0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
