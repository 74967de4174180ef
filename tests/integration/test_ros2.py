"""ROS 2 tf over rmw_zenoh (issue [bridges] items 1 and 2), on real zenoh sessions and
processes on loopback, checked with code nobody here wrote: rosbags' CDR deserialiser and
serialiser, zenoh-ext's serializer and its AdvancedSubscriber/AdvancedPublisher configured as
rmw_zenoh configures a transient-local subscription and publisher."""

from __future__ import annotations

import json
import queue
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

rosbags_typesys = pytest.importorskip(
    "rosbags.typesys", reason="the ros2 extra (rosbags) is not installed"
)
import zenoh  # noqa: E402
import zenoh.ext  # noqa: E402

from tests.integration.zenoh_helpers import free_port, wait_until  # noqa: E402
from ubitrack_agent.core import Pose, decode  # noqa: E402
from ubitrack_agent.io.provider import EdgeAnnouncement, Provider  # noqa: E402
from ubitrack_agent.io.ros2.cdr import Transform  # noqa: E402
from ubitrack_agent.io.ros2.keys import TF_TYPE, topic_key  # noqa: E402
from ubitrack_agent.io.ros2.publisher import TfPublisher  # noqa: E402
from ubitrack_agent.net import config  # noqa: E402
from ubitrack_agent.net.keys import KeySpace  # noqa: E402
from ubitrack_agent.net.session import open_session  # noqa: E402
from ubitrack_agent.net.transport import fetch_latest  # noqa: E402

pytestmark = pytest.mark.integration

JAZZY = rosbags_typesys.get_typestore(rosbags_typesys.Stores.ROS2_JAZZY)
Int64 = zenoh.ext.Int64
ATTACHMENT = tuple[str, Int64, str, Int64, str, bytes]


def hub(port: int, domain: str = "ros2") -> config.Settings:
    return config.Settings(listen=(f"tcp/127.0.0.1:{port}",), domain=domain)


def ros_side(settings: config.Settings):
    """A session standing for a ROS 2 process (rmw_zenoh peers connect to one router)."""
    return open_session(config.member_of(settings))


def received(sample) -> tuple[list, tuple]:
    """A sample decoded by rosbags (payload) and zenoh-ext (attachment)."""
    message = JAZZY.deserialize_cdr(sample.payload.to_bytes(), TF_TYPE)
    attachment = zenoh.ext.z_deserialize(ATTACHMENT, sample.attachment)
    return message.transforms, attachment


def first_static_message(session, key: str, timeout: float) -> tuple[list, tuple]:
    """The first /tf_static message a subscriber joining now receives, subscribed as rmw_zenoh
    subscribes a transient-local topic (rmw_subscription_data.cpp), decoded (:func:`received`)."""
    samples: queue.SimpleQueue = queue.SimpleQueue()
    subscriber = zenoh.ext.declare_advanced_subscriber(
        session,
        key,
        samples.put,
        history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=100),
        recovery=zenoh.ext.RecoveryConfig(heartbeat=True),
        subscriber_detection=True,
    )
    try:
        return received(samples.get(timeout=timeout))
    finally:
        subscriber.undeclare()


def test_a_subscriber_joining_later_receives_the_whole_static_tree():
    settings = hub(free_port())
    with open_session(settings) as session, TfPublisher(session, domain_id=4) as publisher:
        publisher.publish_static([Transform("world", "cam", 10, (1, 2, 3), (0, 0, 0, 1))])
        publisher.publish_static([Transform("world", "ht", 20, (4, 5, 6), (0, 0.6, 0, 0.8))])
        with ros_side(settings) as ros:
            transforms, attachment = first_static_message(ros, topic_key(4, "/tf_static"), 10)
            tokens = [str(r.ok.key_expr) for r in ros.liveliness().get("@ros2_lv/4/**") if r.ok]
    assert [(t.header.frame_id, t.child_frame_id) for t in transforms] == [
        ("world", "cam"),
        ("world", "ht"),
    ]
    ht = transforms[1].transform
    assert (ht.translation.x, ht.translation.y, ht.translation.z) == (4, 5, 6)
    assert (ht.rotation.y, ht.rotation.w) == (0.6, 0.8)
    assert transforms[1].header.stamp.nanosec == 20
    assert attachment[0::2] == ("sequence_number", "source_timestamp", "source_gid")
    assert attachment[1] == 2 and len(attachment[5]) == 16  # the second static message
    assert abs(attachment[3] - time.time_ns()) < 60e9
    kinds = sorted(token.split("/")[5] for token in tokens)
    assert kinds == ["MP", "MP", "NN"]
    assert any("/%tf_static/tf2_msgs::msg::dds_::TFMessage_/RIHS01_" in t for t in tokens)


def test_dynamic_transforms_go_on_tf_with_counting_sequence_numbers():
    settings = hub(free_port())
    with (
        open_session(settings) as session,
        TfPublisher(session, domain_id=0) as publisher,
        ros_side(settings) as ros,
    ):
        samples: queue.SimpleQueue = queue.SimpleQueue()
        subscriber = ros.declare_subscriber(publisher.keys[0], samples.put)
        try:

            def first_arrives():  # publish until the subscription is matched
                publisher.publish([Transform("A", "B", 5_000_000_001, (0.1, 0, 0), (0, 0, 0, 1))])
                try:
                    return received(samples.get(timeout=0.2))
                except queue.Empty:
                    return None

            first = wait_until(first_arrives, timeout=10)
            while not samples.empty():
                first = received(samples.get())
            publisher.publish([Transform("A", "B", 5_000_000_002, (0.2, 0, 0), (0, 0, 0, 1))])
            second = received(samples.get(timeout=5))
        finally:
            subscriber.undeclare()
    assert publisher.keys[0].startswith("0/tf/tf2_msgs::msg::dds_::TFMessage_/RIHS01_")
    assert second[1][1] == first[1][1] + 1  # sequence numbers count per message
    assert first[1][5] == second[1][5]  # one publisher, one gid
    (transform,) = second[0]
    assert (transform.header.stamp.sec, transform.header.stamp.nanosec) == (5, 2)
    assert transform.transform.translation.x == 0.2


def rosbags_tf(parent: str, child: str, stamp_ns: int, xyz) -> bytes:
    t = JAZZY.types
    stamped = t["geometry_msgs/msg/TransformStamped"](
        header=t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9),
            frame_id=parent,
        ),
        child_frame_id=child,
        transform=t["geometry_msgs/msg/Transform"](
            translation=t["geometry_msgs/msg/Vector3"](*map(float, xyz)),
            rotation=t["geometry_msgs/msg/Quaternion"](0.0, 0.0, 0.0, 1.0),
        ),
    )
    return bytes(JAZZY.serialize_cdr(t[TF_TYPE](transforms=[stamped]), TF_TYPE))


def rmw_attachment(sequence: int) -> bytes:
    return zenoh.ext.z_serialize(
        ("sequence_number", Int64(sequence), "source_timestamp", Int64(time.time_ns()),
         "source_gid", bytes(range(16)))
    ).to_bytes()  # fmt: skip


def test_a_robots_tf_tree_becomes_srg_edges(processes, tmp_path):
    port = free_port()
    settings = hub(port, domain=f"ros2in{port}")
    keys = KeySpace(settings.key_prefix)
    with open_session(settings) as session:
        # The robot's static tree, published before the bridge starts (a late joiner).
        static = zenoh.ext.declare_advanced_publisher(
            session,
            topic_key(3, "/tf_static"),
            cache=zenoh.ext.CacheConfig(max_samples=1),
            sample_miss_detection=zenoh.ext.MissDetectionConfig(sporadic_heartbeat=0.5),
            publisher_detection=True,
        )  # as rmw_zenoh declares a reliable transient-local publisher
        static.put(rosbags_tf("map", "odom", 0, (1, 2, 3)), attachment=rmw_attachment(1))
        log = tmp_path / "bridge.log"
        with log.open("w") as stderr:  # the child keeps its own descriptor
            bridge = subprocess.Popen(
                [sys.executable, "-m", "ubitrack_agent.cli", "ros2", "subscribe", "--quiet",
                 "--ros-domain-id", "3", "--provider", "robot", *config.member_flags(settings)],
                start_new_session=True,
                stderr=stderr,
            )  # fmt: skip
        processes.append(bridge)
        dynamic = session.declare_publisher(topic_key(3, "/tf"))
        sequence = 0

        def announced() -> dict | None:
            nonlocal sequence
            sequence += 1
            stamp = time.time_ns()
            payload = rosbags_tf("odom", "robot1/base_link", stamp, (0.5, 0, 0))
            dynamic.put(payload, attachment=rmw_attachment(sequence))
            dynamic.put(b"\x00\x01garbage", attachment=rmw_attachment(sequence))  # rejected
            dynamic.put(payload)  # no attachment: rejected, as rmw_zenoh drops it
            fragments = fetch_latest(session, keys.fragment("robot"), timeout=0.5)
            fragment = json.loads(fragments[0]) if fragments else None
            return fragment if fragment and len(fragment["edges"]) == 2 else None

        fragment = wait_until(announced, timeout=30, interval=0.2)
        edges = {(e["from"], e["to"]): e["static"] for e in fragment["edges"]}
        assert edges == {("map", "odom"): True, ("odom", "robot1.base_link"): False}
        values = fetch_latest(session, keys.measured("robot", "odom_robot1.base_link"))
        pose = decode(values[0])
        np.testing.assert_allclose(pose.translation, [0.5, 0, 0])
        assert abs(pose.timestamp_ns - time.time_ns()) < 30e9  # the header stamp
        static_value = decode(fetch_latest(session, keys.measured("robot", "map_odom"))[0])
        np.testing.assert_allclose(static_value.translation, [1, 2, 3])
        tokens = [str(r.ok.key_expr) for r in session.liveliness().get("@ros2_lv/3/**") if r.ok]
        assert sorted(t.split("/")[5] for t in tokens) == ["MS", "MS", "NN"]
        static.undeclare()
        dynamic.undeclare()
    bridge.terminate()
    assert bridge.wait(timeout=10) == 0
    logged = log.read_text()  # the hostile samples: rejected, logged, not fatal
    assert "rejected input" in logged
    assert "attachment: no attachment" in logged and "payload: not a TFMessage" in logged


def test_ros2_publish_follows_relations_onto_tf_and_tf_static(processes):
    port = free_port()
    settings = hub(port, domain=f"ros2out{port}")
    keys = KeySpace(settings.key_prefix)
    command = [sys.executable, "-m", "ubitrack_agent.cli"]
    processes.append(
        subprocess.Popen([*command, "agent", *config.as_flags(settings)], start_new_session=True)
    )
    edges = [
        EdgeAnnouncement("A", "B", "6D", rate=50.0),
        EdgeAnnouncement("W", "A", "6D", static=True),
    ]
    stop = threading.Event()
    with (
        open_session(config.member_of(settings)) as session,
        Provider(session, keys, "sensor", edges) as provider,
    ):
        provider.publish("W_A", Pose(time.time_ns(), [0, 0, 0, 1], [7.0, 0, 0]))
        stamps: list[int] = []

        def measure() -> None:
            while not stop.wait(0.02):
                stamps.append(time.time_ns())
                provider.publish("A_B", Pose(stamps[-1], [0, 0, 0, 1], [0.3, 0.2, 0.1]))

        sensor = threading.Thread(target=measure, daemon=True)
        sensor.start()
        processes.append(
            subprocess.Popen(
                [*command, "ros2", "publish", "A/B", "--static", "W/A", "--quiet",
                 "--ros-domain-id", "9", *config.member_flags(settings)],
                start_new_session=True,
            )
        )  # fmt: skip
        dynamic: queue.SimpleQueue = queue.SimpleQueue()
        subscriber = session.declare_subscriber(topic_key(9, "/tf"), dynamic.put)
        try:
            transforms, attachment = received(dynamic.get(timeout=90))
            time.sleep(1.0)  # then join /tf_static late
            static_transforms, _ = first_static_message(session, topic_key(9, "/tf_static"), 60)
        finally:
            stop.set()
            sensor.join(timeout=2)
            subscriber.undeclare()
    assert transforms  # samples that came in one burst go out in one TFMessage (relations.py)
    for transform in transforms:
        assert (transform.header.frame_id, transform.child_frame_id) == ("A", "B")
        stamp = transform.header.stamp.sec * 10**9 + transform.header.stamp.nanosec
        assert stamp in stamps  # the measurement's timestamp
        xyz = transform.transform.translation
        np.testing.assert_allclose([xyz.x, xyz.y, xyz.z], [0.3, 0.2, 0.1])
    assert attachment[1] >= 1
    assert [(t.header.frame_id, t.child_frame_id) for t in static_transforms] == [("W", "A")]
    assert static_transforms[0].transform.translation.x == pytest.approx(7.0)


def test_a_missing_extra_is_named():
    """In a process of its own, where rosbags cannot be imported."""
    code = (
        "import sys; sys.modules['rosbags'] = None\n"  # as if rosbags were not installed
        "from ubitrack_agent.cli import main\n"
        "sys.exit(main(['ros2', 'publish', 'C/A']))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert 'needs the ros2 extra: pip install "ubitrack-agent[ros2]"' in out.stderr
