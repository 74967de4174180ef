"""The baseline hop of ``bench.dataflow_bench``: republish every payload from one key on another,
with zenoh-python's own receive loop and nothing else (no decoding, no computation).

With ``--compose minimal`` or ``--compose package``, the same loop composes each ErrorPose with
the bench's static edge (``bench.dataflow_bench.STATIC``) before republishing it, as a
concatenation worker does: by the maths and checks written flat (``minimal``, a lower bound for
a hop in Python), or by the package's own steps without a worker around them (``package``);
both from ``bench.hop_cost_bench``. They tell, live and side by side with the raw relay and the
worker, what the maths costs and what the worker adds.

With ``--receive queue`` (and no ``--compose``), the raw relay takes each sample as a worker
does: zenoh calls back on its own thread, the callback puts the payload on a
``queue.SimpleQueue``, the loop's thread takes it (``ubitrack_agent.services.worker.Inbox``); it
tells what that hand-over costs against zenoh's own channel.

Run: ``python -m bench.raw_relay IN_KEY OUT_KEY [--compose minimal|package | --receive queue]
[zenoh flags]``; ends on SIGTERM.
"""

from __future__ import annotations

import argparse
import queue
import threading
from collections.abc import Callable
from typing import Any

import zenoh

from ubitrack_agent.net import config
from ubitrack_agent.net.lifecycle import stop_on_signals
from ubitrack_agent.net.session import open_session


def relay(subscriber: Any, publisher: Any) -> None:
    """Republish each sample's payload as it is; ends when the subscriber is undeclared."""
    for sample in subscriber:
        publisher.put(sample.payload)


def relay_handed_over(items: queue.SimpleQueue[bytes | None], publisher: Any) -> None:
    """Republish each payload a callback put on ``items``; ends when it holds None."""
    while (payload := items.get()) is not None:
        publisher.put(payload)


def relay_composed(subscriber: Any, hop: Callable[[bytes], None]) -> None:
    """Hand each sample's payload to ``hop``, which publishes the composition."""
    for sample in subscriber:
        hop(sample.payload.to_bytes())


def main() -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.raw_relay")
    parser.add_argument("source")
    parser.add_argument("target")
    how = parser.add_mutually_exclusive_group()
    how.add_argument("--compose", choices=("minimal", "package"), help="see the docstring")
    how.add_argument(
        "--receive", choices=("channel", "queue"), default="channel", help="see the docstring"
    )
    config.add_arguments(parser)
    args = parser.parse_args()
    stop = stop_on_signals()
    with open_session(config.from_arguments(args, role="member")) as session:
        publisher = session.declare_publisher(args.target)
        items: queue.SimpleQueue[bytes | None] = queue.SimpleQueue()
        if args.receive == "queue":
            subscriber = session.declare_subscriber(
                args.source, lambda sample: items.put(sample.payload.to_bytes())
            )
            thread = threading.Thread(
                target=relay_handed_over, args=(items, publisher), daemon=True
            )
        elif args.compose is None:
            subscriber = session.declare_subscriber(args.source, zenoh.handlers.FifoChannel(4096))
            thread = threading.Thread(target=relay, args=(subscriber, publisher), daemon=True)
        else:
            subscriber = session.declare_subscriber(args.source, zenoh.handlers.FifoChannel(4096))
            from bench.hop_cost_bench import minimal_hop, package_hop

            hop = (minimal_hop if args.compose == "minimal" else package_hop)(publisher)
            thread = threading.Thread(target=relay_composed, args=(subscriber, hop), daemon=True)
        thread.start()
        stop.wait()
        subscriber.undeclare()
        items.put(None)
        thread.join(timeout=1.0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
