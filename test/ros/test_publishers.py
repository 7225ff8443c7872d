"""Output publishers without QoS-event handlers still report a subscriber that cannot match."""
from __future__ import annotations

import pytest

pytest.importorskip("rclpy")

from geometry_msgs.msg import PoseStamped  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402

from eye_in_hand.ros.publishers import OutputPublishers  # noqa: E402
from eye_in_hand.ros.qos import RESULT_QOS, SENSOR_QOS  # noqa: E402


def test_incompatible_subscribers_are_reported_once_each(ros_context, executor, namespace,
                                                         spin_until):
    node = Node("out", context=ros_context, namespace=namespace)
    other = Node("viewer", context=ros_context, namespace=namespace)
    reports: list[tuple[str, str]] = []
    outputs = OutputPublishers(node, lambda cause, text: reports.append((cause, text)),
                               period_s=3600.0)
    volatile = outputs.create(PoseStamped, "pose", RESULT_QOS)
    outputs.create(PoseStamped, "image_like", SENSOR_QOS)          # best effort
    assert volatile.event_handlers == []        # nothing added to every wake-up's wait set
    for n in (node, other):
        executor.add_node(n)
    other.create_subscription(PoseStamped, "pose", lambda m: None, RESULT_QOS)   # matches
    other.create_subscription(PoseStamped, "pose", lambda m: None, QoSProfile(
        depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    other.create_subscription(PoseStamped, "image_like", lambda m: None, QoSProfile(
        depth=1, reliability=ReliabilityPolicy.RELIABLE))
    assert spin_until(executor, lambda: len(node.get_subscriptions_info_by_topic(
        f"{namespace}/pose")) == 2 and node.get_subscriptions_info_by_topic(
        f"{namespace}/image_like"), 10.0)
    texts = outputs.check()
    assert len(texts) == 2 and [c for c, _ in reports] == ["incompatible_qos"] * 2
    assert f"{namespace}/pose: subscription of {namespace}/viewer" in texts[0]
    assert "transient local" in texts[0].lower()
    assert f"{namespace}/image_like" in texts[1] and "reliab" in texts[1].lower()
    assert outputs.check() == [] and len(reports) == 2     # each one once
    outputs.destroy()
