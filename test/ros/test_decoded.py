"""ros.decoded: subscriptions that take serialized messages and decode them with a given
decoder (the nodes give rosbags' CDR decoder); bytes that do not decode are reported."""
from __future__ import annotations

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from geometry_msgs.msg import PoseWithCovarianceStamped  # noqa: E402
from rclpy.node import Node  # noqa: E402
from visualization_msgs.msg import MarkerArray  # noqa: E402

from eye_in_hand.io.bags.decoding import jazzy_decoder  # noqa: E402
from eye_in_hand.ros.decoded import (  # noqa: E402
    decode_each,
    decoded_subscription,
    msgtype_of,
    undecodable,
)
from eye_in_hand.ros.executor import set_passive, take_queued  # noqa: E402
from eye_in_hand.ros.markers import spheres_from_marker_array  # noqa: E402
from eye_in_hand.ros.outputs import (  # noqa: E402
    Sphere,
    pose_with_covariance,
    rclpy_types,
    sphere_markers,
)

QOS = 20


def test_msgtype_of_rclpy_classes():
    assert msgtype_of(PoseWithCovarianceStamped) == "geometry_msgs/msg/PoseWithCovarianceStamped"
    assert msgtype_of(MarkerArray) == "visualization_msgs/msg/MarkerArray"


def test_messages_arrive_decoded_and_bad_bytes_are_reported(ros_context, executor, namespace,
                                                            spin_until):
    node = Node("decoded", namespace=namespace, context=ros_context)
    executor.add_node(node)
    got: list = []
    bad: list = []
    decoded_subscription(node, PoseWithCovarianceStamped, "cov", got.append, QOS,
                         decoder_for=jazzy_decoder, on_bad=lambda t, e: bad.append((t, e)))
    markers: list = []
    decoded_subscription(node, MarkerArray, "markers", markers.append, QOS,
                         decoder_for=jazzy_decoder, on_bad=lambda t, e: bad.append((t, e)))
    pub = node.create_publisher(PoseWithCovarianceStamped, "cov", QOS)
    pub_m = node.create_publisher(MarkerArray, "markers", QOS)
    assert spin_until(executor, lambda: pub.get_subscription_count() == 1
                      and pub_m.get_subscription_count() == 1, 5.0)
    T = rclpy_types()
    cov = np.arange(9.0).reshape(3, 3) * 1e-9
    pub.publish(pose_with_covariance(T, (0.1, -0.2, 0.3), cov, 1_700_000_000_123_456_789,
                                     "camera_left_optical_frame"))
    pub.publish(b"\x00\x01\x00\x00\x05")               # too short for the header
    spheres = [Sphere("red_0", (0.1, 0.2, 0.3), 0.05, (1.0, 0.0, 0.0, 1.0)),
               Sphere("blue", (0.4, 0.5, 0.6), 0.07, (0.0, 0.0, 1.0, 0.5))]
    pub_m.publish(sphere_markers(T, spheres, 42, "cam", lifetime_s=0.5))
    assert spin_until(executor, lambda: got and bad and markers, 5.0)
    msg = got[0]
    assert msg.header.stamp.sec == 1_700_000_000 and msg.header.stamp.nanosec == 123_456_789
    assert msg.header.frame_id == "camera_left_optical_frame"
    assert (msg.pose.pose.position.x, msg.pose.pose.position.y,
            msg.pose.pose.position.z) == (0.1, -0.2, 0.3)
    full = np.asarray(msg.pose.covariance).reshape(6, 6)
    assert np.array_equal(full[:3, :3], cov)
    topic, exc = bad[0]
    assert topic == f"{namespace}/cov"
    assert undecodable(topic, exc).startswith(f"{namespace}/cov: a message that does not decode")
    # the package's readers take the decoded message as they take rclpy's
    stamp, frame, read = spheres_from_marker_array(markers[0])
    assert (stamp, frame) == (42, "cam")
    assert [(s.id, tuple(s.xyz), s.diameter_m, tuple(s.rgba)) for s in read] == \
        [(s.id, tuple(s.xyz), s.diameter_m, tuple(s.rgba)) for s in spheres]


def test_messages_taken_outside_the_callback_are_decoded(ros_context, executor, namespace,
                                                         spin_until):
    node = Node("decoded_lazy", namespace=namespace, context=ros_context)
    executor.add_node(node)
    seen: list = []
    bad: list = []
    sub = decoded_subscription(node, PoseWithCovarianceStamped, "cov", seen.append, QOS,
                               decoder_for=jazzy_decoder, on_bad=lambda t, e: bad.append(t))
    set_passive(sub, True)
    pub = node.create_publisher(PoseWithCovarianceStamped, "cov", QOS)
    assert spin_until(executor, lambda: pub.get_subscription_count() == 1, 5.0)
    T = rclpy_types()
    pub.publish(b"\x00\x01\x00\x00")
    for k in range(3):
        pub.publish(pose_with_covariance(T, (k, 0, 1), np.eye(3), 10 + k, "c"))
    taken: list = []
    assert spin_until(executor, lambda: taken.extend(take_queued(sub)) or len(taken) == 4, 5.0)
    out = decode_each(sub, taken, lambda t, e: bad.append(t))
    assert [m.header.stamp.nanosec for m, _ in out] == [10, 11, 12]
    assert all(t > 0 for _, t in out) and bad == [f"{namespace}/cov"] and not seen
