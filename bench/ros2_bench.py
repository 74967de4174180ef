"""What the ROS 2 tf bridge (``ubitrack ros2``, ``docs/ros2.md``) costs per sample, both ways.

Run: ``python -m bench.ros2_bench [--samples N] [--gap-ms G] [--transforms K]``; prints the
figures and writes them to ``bench/results/ros2.json``.

Two zenoh sessions in one process on loopback (a hub and a member, multicast off), standing
for this project's process and a ROS 2 process. Per direction, a sample goes through the
bridge and, interleaved sample by sample, through the plain project path it replaces:

* **out** (``ros2 publish``): a 6D sample of a relation -> ``transform_of`` -> a TFMessage in
  CDR (rosbags) with the rmw_zenoh attachment put on /tf -> a ROS-side subscriber decoding it
  with rosbags. Baseline: the same sample ``encode``-d (msgpack) and put on a relation key ->
  a subscriber ``decode``-ing it, what an application of this project receives.
* **in** (``ros2 subscribe``): a ROS-side put of a rosbags-serialised TFMessage with the
  attachment on /tf -> ``TfSubscriber`` -> ``TfAdapter`` -> ``GrowingProvider`` -> a
  subscriber on the edge's measured key ``decode``-ing the pose. Baseline: a relay over the
  same two hops that does nothing else: a plain subscriber in the project's session receiving
  the same bytes on another key and, in zenoh's callback, a
  :class:`~ubitrack_agent.io.provider.Provider` publishing a pose to the same kind of
  subscriber. The difference is the bridge's own work: the hand-over to its reader thread,
  the attachment and CDR checks, the frame mapping and the pose's construction.

Latency is the time from the send to the decoded arrival (``perf_counter_ns``, one clock),
one sample in flight at a time, every ``--gap-ms``; the added latency is the difference of
the medians. Out, the hand-over from a relation's zenoh callback to the publishing thread
(``RelationsToTf.pump``) is not included (the in path measures such a hand-over).
Throughput is samples per second of the bridge's own work in a tight loop
(out: ``transform_of`` + ``TfPublisher.publish``; in: ``TfAdapter.handle`` including the
provider's put), with one transform per message and with ``--transforms`` (a tf tree's burst).
"""

from __future__ import annotations

import argparse
import os
import platform
import queue
import statistics
import threading
import time
from importlib.metadata import version
from pathlib import Path
from typing import Any

import zenoh
import zenoh.ext

from bench.report import write_results
from ubitrack_agent.core import ErrorPose, decode, encode
from ubitrack_agent.io.provider import EdgeAnnouncement, Provider
from ubitrack_agent.io.ros2.cdr import Transform, encode_tf, typestore
from ubitrack_agent.io.ros2.keys import TF_TYPE, topic_key
from ubitrack_agent.io.ros2.provider import GrowingProvider, TfAdapter, serve_tf
from ubitrack_agent.io.ros2.publisher import TfPublisher
from ubitrack_agent.io.ros2.relations import transform_of
from ubitrack_agent.io.ros2.subscriber import TfSample, TfSubscriber
from ubitrack_agent.net import config
from ubitrack_agent.net.keys import KeySpace, RelationId
from ubitrack_agent.net.session import open_session

RESULTS = Path(__file__).parent / "results" / "ros2.json"
COVARIANCE = [[1e-6 if i == j else 0.0 for j in range(6)] for i in range(6)]


def pose(timestamp_ns: int, x: float = 0.3) -> ErrorPose:
    return ErrorPose(timestamp_ns, [0, 0, 0, 1], [x, 0.2, 0.1], COVARIANCE)


def attachment(sequence: int) -> bytes:
    Int64 = zenoh.ext.Int64
    return zenoh.ext.z_serialize(
        ("sequence_number", Int64(sequence), "source_timestamp", Int64(time.time_ns()),
         "source_gid", bytes(16))
    ).to_bytes()  # fmt: skip


def medians_us(values_ns: list[int]) -> dict[str, float]:
    ordered = sorted(values_ns)
    return {
        "median_us": round(statistics.median(ordered) / 1e3, 1),
        "p90_us": round(ordered[int(0.9 * (len(ordered) - 1))] / 1e3, 1),
    }


def interleaved(paths: list[tuple[Any, queue.SimpleQueue]], n: int, gap_s: float) -> list:
    """Latencies (ns) of ``n`` samples through each ``(send, arrivals)`` path, taking turns
    sample by sample, one in flight at a time (each arrival puts its ``perf_counter_ns``)."""
    latencies: list[list[int]] = [[] for _ in paths]
    for i in range(n):
        for (send, arrivals), out in zip(paths, latencies, strict=True):
            start = time.perf_counter_ns()
            send(i)
            out.append(arrivals.get(timeout=5) - start)
            time.sleep(gap_s)
    return latencies


def figures(base: list[int], bridge: list[int]) -> dict[str, Any]:
    return {
        "baseline_latency": medians_us(base),
        "bridge_latency": medians_us(bridge),
        "added_latency_median_us": round(
            (statistics.median(bridge) - statistics.median(base)) / 1e3, 1
        ),
    }


def rate(work: Any, seconds: float = 2.0) -> float:
    """Calls of ``work`` per second in a tight loop of about ``seconds``."""
    calls, end = 0, time.perf_counter() + seconds
    while time.perf_counter() < end:
        work(calls)
        calls += 1
    return calls / seconds


def bench_out(hub: Any, ros: Any, args: argparse.Namespace) -> dict[str, Any]:
    relation = RelationId("A", "B", "6D")
    names = {"A": "A", "B": "B"}
    ours: queue.SimpleQueue[int] = queue.SimpleQueue()
    theirs: queue.SimpleQueue[int] = queue.SimpleQueue()
    store = typestore()
    with TfPublisher(hub, domain_id=0) as publisher:
        baseline_key = "bench/ros2/relation"
        baseline_pub = hub.declare_publisher(baseline_key)

        def on_ours(sample: Any) -> None:
            decode(sample.payload.to_bytes())
            ours.put(time.perf_counter_ns())

        def on_theirs(sample: Any) -> None:
            store.deserialize_cdr(sample.payload.to_bytes(), TF_TYPE)
            theirs.put(time.perf_counter_ns())

        subscribers = [
            ros.declare_subscriber(baseline_key, on_ours),
            ros.declare_subscriber(publisher.keys[0], on_theirs),
        ]
        time.sleep(1.0)  # let the subscriptions reach the publishers
        base, bridge = interleaved(
            [
                (lambda _: baseline_pub.put(encode(pose(time.time_ns()))), ours),
                (
                    lambda _: publisher.publish(
                        [transform_of(relation, pose(time.time_ns()), names)]
                    ),
                    theirs,
                ),
            ],
            args.samples,
            args.gap_ms / 1000,
        )
        for subscriber in subscribers:
            subscriber.undeclare()
        baseline_pub.undeclare()
        many = [
            Transform("A", f"B{k}", time.time_ns(), (0.1, 0, 0), (0, 0, 0, 1))
            for k in range(args.transforms)
        ]
        one_rate = rate(
            lambda _: publisher.publish([transform_of(relation, pose(time.time_ns()), names)])
        )
        many_rate = rate(lambda _: publisher.publish(many)) * args.transforms
    return {
        **figures(base, bridge),
        "samples_per_s_one_per_message": round(one_rate),
        f"samples_per_s_{args.transforms}_per_message": round(many_rate),
        "cdr_bytes_one_transform": len(encode_tf(many[:1])),
    }


def bench_in(hub: Any, ros: Any, args: argparse.Namespace) -> dict[str, Any]:
    keys = KeySpace("bench/ros2in")
    arrivals: queue.SimpleQueue[int] = queue.SimpleQueue()
    ros_tf = ros.declare_publisher(topic_key(0, "/tf"))
    payload = encode_tf([Transform("odom", "base", time.time_ns(), (0.5, 0, 0), (0, 0, 0, 1))])
    adapter = TfAdapter()
    stop = threading.Event()
    baseline_edges = [EdgeAnnouncement("ART", "HT", "6D")]
    ros_raw = ros.declare_publisher("bench/ros2/raw")

    def arrived(sample: Any) -> None:
        decode(sample.payload.to_bytes())
        arrivals.put(time.perf_counter_ns())

    with (
        TfSubscriber(hub, 0) as subscriber,
        GrowingProvider(hub, keys, "robot", lambda: adapter.edges) as provider,
        Provider(hub, keys, "art", baseline_edges) as baseline,
    ):
        reader = threading.Thread(target=serve_tf, args=(subscriber, adapter, provider, stop))
        reader.start()
        watch = [
            hub.declare_subscriber(keys.measured("robot", "odom_base"), arrived),
            hub.declare_subscriber(keys.measured("art", "ART_HT"), arrived),
            # the relay: the same two hops, the pose published from zenoh's callback at once
            hub.declare_subscriber(
                "bench/ros2/raw", lambda _: baseline.publish("ART_HT", pose(time.time_ns()))
            ),
        ]
        time.sleep(1.0)
        ros_tf.put(payload, attachment=attachment(1))  # announces the edge
        arrivals.get(timeout=10)
        time.sleep(1.0)
        base, bridge = interleaved(
            [
                (lambda n: ros_raw.put(payload, attachment=attachment(n + 1)), arrivals),
                (lambda n: ros_tf.put(payload, attachment=attachment(n + 2)), arrivals),
            ],
            args.samples,
            args.gap_ms / 1000,
        )
        stop.set()
        reader.join()
        for subscription in watch:
            subscription.undeclare()
        many_payload = encode_tf(
            [
                Transform("odom", f"link{k}", time.time_ns(), (0.1, 0, 0), (0, 0, 0, 1))
                for k in range(args.transforms)
            ]
        )
        one = TfSample(False, payload, attachment(1), 0)
        many = TfSample(False, many_payload, attachment(1), 0)
        adapter.handle(many, time.time_ns(), provider)  # announce the links first
        one_rate = rate(lambda _: adapter.handle(one, time.time_ns(), provider))
        many_rate = rate(lambda _: adapter.handle(many, time.time_ns(), provider))
    ros_tf.undeclare()
    ros_raw.undeclare()
    return {
        **figures(base, bridge),
        "samples_per_s_one_per_message": round(one_rate),
        f"samples_per_s_{args.transforms}_per_message": round(many_rate * args.transforms),
        "rejected": adapter.counters["rejected"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=1000)
    parser.add_argument("--gap-ms", type=float, default=2.0)
    parser.add_argument("--transforms", type=int, default=20)
    args = parser.parse_args()
    port = int(os.environ.get("BENCH_PORT", "0")) or _free_port()
    hub_settings = config.Settings(listen=(f"tcp/127.0.0.1:{port}",))
    with open_session(hub_settings) as hub, open_session(config.member_of(hub_settings)) as ros:
        results = {
            "command": f"python -m bench.ros2_bench --samples {args.samples} "
            f"--gap-ms {args.gap_ms} --transforms {args.transforms}",
            "machine": f"{platform.python_version()}, {os.cpu_count()} CPUs, zenoh "
            f"{version('eclipse-zenoh')}, rosbags {version('rosbags')}",
            "date": time.strftime("%Y-%m-%d"),
            "out": bench_out(hub, ros, args),
            "in": bench_in(hub, ros, args),
        }
    write_results(RESULTS, results)


def _free_port() -> int:
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


if __name__ == "__main__":
    main()
