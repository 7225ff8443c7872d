"""Tests of the named QoS profiles."""
from __future__ import annotations

import pytest

pytest.importorskip("rclpy")

from rclpy.qos import (  # noqa: E402
    DurabilityPolicy,
    HistoryPolicy,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

from eye_in_hand.ros.qos import LATCHED_QOS, RESULT_QOS, SENSOR_QOS  # noqa: E402


def test_profiles():
    assert SENSOR_QOS == qos_profile_sensor_data
    assert (SENSOR_QOS.reliability, SENSOR_QOS.history, SENSOR_QOS.depth) == (
        ReliabilityPolicy.BEST_EFFORT, HistoryPolicy.KEEP_LAST, 5)
    assert (RESULT_QOS.reliability, RESULT_QOS.durability, RESULT_QOS.depth) == (
        ReliabilityPolicy.RELIABLE, DurabilityPolicy.VOLATILE, 100)
    assert (LATCHED_QOS.reliability, LATCHED_QOS.durability, LATCHED_QOS.depth) == (
        ReliabilityPolicy.RELIABLE, DurabilityPolicy.TRANSIENT_LOCAL, 1)


def test_latched_topic_reaches_a_late_subscriber(ros_context, executor, namespace, spin_until):
    from rclpy.node import Node
    from std_msgs.msg import String

    pub_node = Node("latched_pub", context=ros_context, namespace=namespace)
    executor.add_node(pub_node)
    pub = pub_node.create_publisher(String, "hand_eye/transform_text", LATCHED_QOS)
    pub.publish(String(data="first"))
    pub.publish(String(data="last"))  # depth 1: only the last one is kept
    sub_node = Node("late_sub", context=ros_context, namespace=namespace)
    executor.add_node(sub_node)
    got: list[str] = []
    sub_node.create_subscription(String, "hand_eye/transform_text",
                                 lambda m: got.append(m.data), LATCHED_QOS)
    assert spin_until(executor, lambda: got == ["last"], 10.0), got


def test_sensor_subscriber_matches_reliable_publisher(ros_context, executor, namespace,
                                                      spin_until):
    from rclpy.node import Node
    from std_msgs.msg import String

    node = Node("qos_match", context=ros_context, namespace=namespace)
    executor.add_node(node)
    pub = node.create_publisher(String, "left/image_raw_text", RESULT_QOS)
    got: list[str] = []
    node.create_subscription(String, "left/image_raw_text", lambda m: got.append(m.data),
                             SENSOR_QOS)
    assert spin_until(executor, lambda: pub.get_subscription_count() >= 1, 10.0)
    pub.publish(String(data="frame"))
    assert spin_until(executor, lambda: got == ["frame"], 10.0), got
