"""``eye-in-hand echo``: messages published by another process, YAML and JSON, timeouts."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

pytest.importorskip("rclpy")

import yaml  # noqa: E402

from eye_in_hand.commands.echo import message_to_dict  # noqa: E402


def _echo(ros_env: dict[str, str], *args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "eye_in_hand.cli", "echo", *args],
                            env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


def _publish_until_done(ros_context, executor, spin_until, proc: subprocess.Popen,
                        topic: str, make) -> tuple[str, str]:
    """Publish make(i) at 50 Hz from this process until the echo process exits."""
    from rclpy.node import Node

    node = Node("echo_test_publisher", context=ros_context)
    msg0 = make(0)
    pub = node.create_publisher(type(msg0), topic, 10)
    count = [0]

    def tick() -> None:
        pub.publish(make(count[0]))
        count[0] += 1

    node.create_timer(0.02, tick)
    executor.add_node(node)
    assert spin_until(executor, lambda: proc.poll() is not None, 40.0), "echo did not finish"
    return proc.communicate(timeout=10)


def test_echo_yaml_of_a_nested_message(ros_context, executor, spin_until, namespace,
                                       ros_env) -> None:
    from geometry_msgs.msg import PointStamped

    def make(i: int) -> PointStamped:
        m = PointStamped()
        m.header.frame_id = "camera_left_optical_frame"
        m.header.stamp.sec = 100 + i
        m.point.x, m.point.y, m.point.z = 0.5, -1.25, float(i)
        return m

    proc = _echo(ros_env, f"{namespace}/target/point", "--count", "2", "--timeout", "30")
    out, err = _publish_until_done(ros_context, executor, spin_until, proc,
                                   f"{namespace}/target/point", make)
    assert proc.returncode == 0, err
    docs = [d for d in out.split("---\n") if d.strip()]
    assert len(docs) == 2
    first = yaml.safe_load(docs[0])
    assert first["header"]["frame_id"] == "camera_left_optical_frame"
    assert first["point"]["x"] == 0.5 and first["point"]["y"] == -1.25
    assert list(first) == ["header", "point"]  # field order as in the message
    second = yaml.safe_load(docs[1])
    assert second["header"]["stamp"]["sec"] == first["header"]["stamp"]["sec"] + 1


def test_echo_json_lines(ros_context, executor, spin_until, namespace, ros_env) -> None:
    from sensor_msgs.msg import JointState

    def make(i: int) -> JointState:
        return JointState(name=["a", "b"], position=[float(i), 2.0], velocity=[], effort=[])

    proc = _echo(ros_env, f"{namespace}/joint_states", "--json", "-n", "3", "-t", "30")
    out, err = _publish_until_done(ros_context, executor, spin_until, proc,
                                   f"{namespace}/joint_states", make)
    assert proc.returncode == 0, err
    lines = out.strip().splitlines()
    assert len(lines) == 3
    objs = [json.loads(line) for line in lines]
    assert all(o["name"] == ["a", "b"] for o in objs)
    positions = [o["position"][0] for o in objs]
    assert positions == [positions[0], positions[0] + 1, positions[0] + 2]


def test_echo_timeout_without_publisher(ros_env, namespace) -> None:
    proc = _echo(ros_env, f"{namespace}/nobody", "--timeout", "1")
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 1
    assert err.strip().splitlines() == [
        f"eye-in-hand: error: topic {namespace}/nobody did not appear within 1 s"]
    proc = _echo(ros_env, f"{namespace}/nobody", "std_msgs/msg/String", "--timeout", "1")
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 1
    assert err.strip().splitlines() == [
        f"eye-in-hand: error: no message received on {namespace}/nobody within 1 s"]


def test_message_to_dict_truncates_long_fields() -> None:
    from sensor_msgs.msg import Image

    msg = Image(height=1, width=200, encoding="mono8", step=200, data=bytes(range(200)))
    d = message_to_dict(msg, truncate_length=5)
    assert d["data"] == [0, 1, 2, 3, 4, "..."]
    assert d["encoding"] == "mono8"
    full = message_to_dict(msg)
    assert full["data"] == list(range(200)) and full["header"]["stamp"] == {"sec": 0,
                                                                            "nanosec": 0}


def test_echo_started_after_a_latched_message_receives_it(ros_context, executor, spin_until,
                                                          namespace, ros_env) -> None:
    """hand_eye/transform (and /tf_static) are latched: an echo started after the message was
    published still prints it (the README tour runs echo at its own pace)."""
    from geometry_msgs.msg import TransformStamped
    from rclpy.node import Node

    from eye_in_hand.ros.qos import LATCHED_QOS

    node = Node("echo_latched_publisher", context=ros_context)
    pub = node.create_publisher(TransformStamped, f"{namespace}/hand_eye/transform", LATCHED_QOS)
    msg = TransformStamped()
    msg.header.frame_id, msg.child_frame_id = "tool0", "camera_left_optical_frame"
    msg.transform.rotation.w = 1.0
    pub.publish(msg)                                  # before echo exists
    executor.add_node(node)
    proc = _echo(ros_env, f"{namespace}/hand_eye/transform", "--count", "1", "--timeout", "30",
                 "--json")
    assert spin_until(executor, lambda: proc.poll() is not None, 40.0), "echo did not finish"
    out, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    assert json.loads(out.splitlines()[0])["child_frame_id"] == "camera_left_optical_frame"
