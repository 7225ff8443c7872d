"""play of /tf and /tf_static: both replayed (tf2_msgs built into the venv), /tf_static
latched (transient local) whatever the bag recorded, so a TF listener that starts after the
playback still gets every static transform."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")

from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from eye_in_hand.io.bags import BagWriter, default_typestore, serialize  # noqa: E402
from eye_in_hand.ros.tf import have_tf2_msgs, tf_qos, tf_static_sub_qos  # noqa: E402

pytestmark = pytest.mark.skipif(not have_tf2_msgs(), reason="tf2_msgs not built (make venv)")

T0 = 1_700_000_000_000_000_000
MS = 1_000_000


def _tf(transforms) -> bytes:
    s = default_typestore().types
    msgs = []
    for parent, child, stamp, x in transforms:
        msgs.append(s["geometry_msgs/msg/TransformStamped"](
            header=s["std_msgs/msg/Header"](stamp=s["builtin_interfaces/msg/Time"](
                sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id=parent),
            child_frame_id=child,
            transform=s["geometry_msgs/msg/Transform"](
                translation=s["geometry_msgs/msg/Vector3"](x=x, y=0.0, z=0.0),
                rotation=s["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))))
    return serialize(s["tf2_msgs/msg/TFMessage"](transforms=msgs), "tf2_msgs/msg/TFMessage")


def _bag(path: Path) -> None:
    with BagWriter(path, "mcap") as bag:       # no QoS recorded: played volatile by default
        bag.add_topic("/tf", "tf2_msgs/msg/TFMessage")
        bag.add_topic("/tf_static", "tf2_msgs/msg/TFMessage")
        # two static publishers (two latched messages), as robot_state_publisher + a camera
        bag.write("/tf_static", T0, _tf([("flange", "tool0", T0, 0.1)]))
        bag.write("/tf_static", T0 + MS, _tf([("tool0", "camera_link", T0, 0.2)]))
        for k in range(5):
            s = T0 + (2 + k) * 10 * MS
            bag.write("/tf", s, _tf([("base_link", "flange", s, 0.01 * k)]))


def test_tf_and_latched_tf_static_replay(tmp_path, ros_context, executor, spin_until,
                                         namespace):
    from tf2_msgs.msg import TFMessage

    from eye_in_hand.core.tf import TfBuffer
    from eye_in_hand.nodes.bag_player import BagPlayer
    from eye_in_hand.ros.tf import add_tf_message

    _bag(tmp_path / "bag")
    remap = ["--ros-args", "-r", f"/tf:={namespace}/tf", "-r",
             f"/tf_static:={namespace}/tf_static"]
    listener = Node("tf_listener", context=ros_context, cli_args=remap)
    buf = TfBuffer()
    dynamic: list = []
    listener.create_subscription(TFMessage, "/tf", dynamic.append, tf_qos())
    player = BagPlayer(context=ros_context, cli_args=remap, parameter_overrides=[
        Parameter("bag", value=str(tmp_path / "bag")),
        Parameter("wait_for_subscribers", value=0.0)])
    executor.add_node(listener)
    executor.add_node(player)
    tf_pub = player.topics.publishers["/tf"]
    assert spin_until(executor, lambda: tf_pub.get_subscription_count() > 0, 10.0)
    player.start()
    assert spin_until(executor, lambda: player.finished and len(dynamic) == 5, 20.0), \
        len(dynamic)
    assert player.error is None and not player.skipped_types
    # a TF listener that starts only now still gets both static messages
    late = Node("late_tf_listener", context=ros_context, cli_args=remap)
    late.create_subscription(TFMessage, "/tf_static",
                             lambda m: add_tf_message(buf, m, static=True),
                             tf_static_sub_qos())
    executor.add_node(late)
    for m in dynamic:
        add_tf_message(buf, m, static=False)
    assert spin_until(executor, lambda: buf.parent("camera_link") == "tool0"
                      and buf.parent("tool0") == "flange", 10.0)
    T = buf.lookup("base_link", "camera_link", T0 + 35 * MS, 20 * MS)
    np.testing.assert_allclose(T[:3, 3], [0.015 + 0.1 + 0.2, 0.0, 0.0], atol=1e-12)
