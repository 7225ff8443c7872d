"""stereo_capture (sim source) publishes the arm as robot_state_publisher would: the moving joints
on /tf, the fixed base_link -> base on /tf_static (once, at the first pair's stamp), so a TF
listener gets the same tool pose as ee_pose; the true stereo extrinsic only when asked
(``sim.publish_stereo_tf``: hand_eye publishes the calibrated one, one publisher a transform)."""
from __future__ import annotations

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from rclpy.parameter import Parameter  # noqa: E402

from eye_in_hand.ros.tf import have_tf2_msgs, tf_qos, tf_static_sub_qos  # noqa: E402

pytestmark = pytest.mark.skipif(not have_tf2_msgs(), reason="tf2_msgs not built (make venv)")


@pytest.mark.parametrize("stereo_tf", [True, False])
def test_sim_tf_chain_matches_ee_pose_and_static_extrinsic_is_latched(
        ros_context, executor, namespace, spin_until, stereo_tf):
    from geometry_msgs.msg import PoseStamped
    from tf2_msgs.msg import TFMessage

    from eye_in_hand.core.tf import TfBuffer
    from eye_in_hand.nodes.stereo_capture import StereoCaptureNode
    from eye_in_hand.ros.geometry import pose_to_matrix
    from eye_in_hand.ros.stamps import header_stamp_ns
    from eye_in_hand.ros.tf import add_tf_message
    from eye_in_hand.sim import World

    remap = ["--ros-args", "-r", f"/tf:={namespace}/tf", "-r",
             f"/tf_static:={namespace}/tf_static"]
    node = StereoCaptureNode(context=ros_context, namespace=namespace, cli_args=remap,
                             parameter_overrides=[
                                 Parameter("source", value="sim"),
                                 Parameter("rate_hz", value=20.0),
                                 Parameter("sim.width", value=160),
                                 Parameter("sim.height", value=90),
                                 Parameter("sim.duration_s", value=1.0),
                                 Parameter("sim.publish_stereo_tf", value=stereo_tf)])
    executor.add_node(node)
    buf = TfBuffer()
    dynamic: list = []
    poses: list = []
    statics: list = []
    listener = rclpy.create_node("tf_listener", context=ros_context, namespace=namespace,
                                 cli_args=remap)
    listener.create_subscription(TFMessage, "/tf",
                                 lambda m: (dynamic.append(m),
                                            add_tf_message(buf, m, static=False)), tf_qos())
    listener.create_subscription(PoseStamped, "ee_pose", poses.append, 10)
    executor.add_node(listener)
    assert spin_until(executor, lambda: len(poses) >= 3, 30.0)
    # a late subscriber still receives the static extrinsic (transient local)
    listener.create_subscription(TFMessage, "/tf_static", statics.append, tf_static_sub_qos())
    assert spin_until(executor, lambda: len(statics) >= 1, 10.0)
    world = World.default()
    assert len(statics) == 1
    for m in statics:
        add_tf_message(buf, m, static=True)
    edges = {(t.header.frame_id, t.child_frame_id): t for t in statics[0].transforms}
    from eye_in_hand.ros.geometry import transform_to_matrix
    assert ("base_link", "base") in edges   # ur_description's fixed joint: static
    assert not any(t.child_frame_id == "base" for m in dynamic for t in m.transforms)
    first_static = header_stamp_ns(statics[0].transforms[0])
    assert {header_stamp_ns(t) for t in edges.values()} == {first_static}
    if stereo_tf:
        tr = edges[("camera_left_optical_frame", "camera_right_optical_frame")]
        np.testing.assert_allclose(transform_to_matrix(tr), world.left_T_right, atol=1e-9)
    else:
        assert len(edges) == 1
    assert buf.parent("tool0") == "wrist_2_link" and buf.parent("shoulder_link") == "base"
    assert buf.parent("base") == "base_link"  # ur_description: base_link -> base, Rz(pi)
    checked = 0
    for p in poses:
        s = header_stamp_ns(p)
        try:
            T = buf.lookup("base_link", "tool0", s, 0)
        except Exception:  # noqa: BLE001 - /tf for that stamp not received yet
            continue
        np.testing.assert_allclose(T, pose_to_matrix(p.pose), atol=1e-9)
        checked += 1
    assert checked >= 2
