"""hand_eye node and TF, in-process: robot pose from /tf + /tf_static (chain, interpolation,
gaps, static frames published before the node starts), and TF out (/tf_static hand-eye and
stereo extrinsic, /tf targets). /tf and /tf_static are remapped into the test's namespace."""
from __future__ import annotations

import numpy as np
import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter

from eye_in_hand.core.kinematics import DHChain
from eye_in_hand.core.localization import target_in_base
from eye_in_hand.core.transforms import from_rotvec, interpolate, invert
from eye_in_hand.io.config import HandEyeCalibration, save_hand_eye
from eye_in_hand.ros.geometry import transform_to_matrix, xyz_to_point_stamped
from eye_in_hand.ros.qos import RESULT_QOS
from eye_in_hand.ros.stamps import header_stamp_ns
from eye_in_hand.ros.tf import (
    chain_tf_edges,
    have_tf2_msgs,
    make_tf_message,
    tf_qos,
    tf_static_pub_qos,
    tf_static_sub_qos,
)

pytestmark = pytest.mark.skipif(not have_tf2_msgs(), reason="tf2_msgs not built (make venv)")

EE_T_CAM = from_rotvec([0.1, -0.2, 0.05], [0.03, -0.05, 0.08])
FLANGE_T_TOOL = from_rotvec([0.0, 0.0, 0.3], [0.0, 0.0, 0.02])
T0 = 1_700_000_000_000_000_000
MS = 1_000_000
CHAIN = DHChain.from_dict({**DHChain.ur5e().to_dict(),
                           "link_names": ["shoulder_link", "upper_arm_link", "forearm_link",
                                          "wrist_1_link", "wrist_2_link", "flange"]})


def _q(t_s: float) -> np.ndarray:
    return np.array([0.1, -1.2, 1.3, -1.6, -1.5, 0.2]) + 0.5 * t_s


def _hand_eye_file(tmp_path):
    path = tmp_path / "hand_eye.yaml"
    save_hand_eye(path, HandEyeCalibration(
        setup="eye_in_hand", parent_frame="tool0", child_frame="camera_left_optical_frame",
        transform=EE_T_CAM, method="refined", covariance=None, sample_count=15))
    return path


def _stereo_dir(tmp_path):
    from eye_in_hand.sim.world import World

    rig = World.default().rig
    rig.save(tmp_path / "stereo")
    return tmp_path / "stereo", rig


def _remap(namespace):
    return ["--ros-args", "-r", f"/tf:={namespace}/tf", "-r", f"/tf_static:={namespace}/tf_static"]


class _Cell:
    """A robot_state_publisher stand-in (arm joints on /tf, flange -> tool0 on /tf_static)
    and a hand_eye node taking its robot pose from TF."""

    def __init__(self, ros_context, executor, namespace, tmp_path, **params):
        from geometry_msgs.msg import PointStamped, PoseStamped
        from tf2_msgs.msg import TFMessage

        self.io = Node("rsp", context=ros_context, namespace=namespace, cli_args=_remap(namespace))
        executor.add_node(self.io)
        self.pub_tf = self.io.create_publisher(TFMessage, "/tf", tf_qos())
        self.pub_static = self.io.create_publisher(TFMessage, "/tf_static", tf_static_pub_qos())
        # static transform published before the hand_eye node exists (transient local)
        self.pub_static.publish(make_tf_message([("flange", "tool0", T0, FLANGE_T_TOOL)]))
        self.stereo_dir, self.rig = _stereo_dir(tmp_path)
        overrides = {"hand_eye_file": str(_hand_eye_file(tmp_path)), "robot_pose_source": "tf",
                     "robot_sigma_pos_m": 0.0, "robot_sigma_rot_rad": 0.0,
                     "stereo_calibration_dir": str(self.stereo_dir), **params}
        from eye_in_hand.nodes.hand_eye import HandEyeNode

        self.node = HandEyeNode(context=ros_context, namespace=namespace,
                                parameter_overrides=[Parameter(k, value=v)
                                                     for k, v in overrides.items()],
                                cli_args=_remap(namespace))
        executor.add_node(self.node)
        self.pub_point = self.io.create_publisher(PointStamped, "target/point", RESULT_QOS)
        self.poses, self.tf_out, self.static_out = [], [], []
        self.io.create_subscription(PoseStamped, "target/pose", self.poses.append, RESULT_QOS)
        self.io.create_subscription(TFMessage, "/tf", self.tf_out.append, tf_qos())
        self.io.create_subscription(TFMessage, "/tf_static", self.static_out.append,
                                    tf_static_sub_qos())

    def connected(self):
        return (self.pub_point.get_subscription_count() > 0
                and self.pub_tf.get_subscription_count() > 1   # the node and our listener
                and self.io.count_publishers("target/pose") > 0)

    def send_joints(self, t_s):
        stamp = T0 + int(round(t_s * 1e9))
        self.pub_tf.publish(make_tf_message(
            (p, c, stamp, T) for p, c, T in chain_tf_edges(CHAIN, _q(t_s))))

    def send_point(self, t_s, p):
        self.pub_point.publish(xyz_to_point_stamped(p, stamp_ns=T0 + int(round(t_s * 1e9)),
                                                    frame_id="camera_left_optical_frame"))

    def base_T_tool(self, t_s):
        return CHAIN.fk(_q(t_s)) @ FLANGE_T_TOOL


def test_robot_pose_from_tf_chain_interpolated_at_the_image_stamp_and_tf_out(
        tmp_path, ros_context, executor, namespace, spin_until):
    # target_frame: a second /tf name for the first target (target/point), opted in here
    cell = _Cell(ros_context, executor, namespace, tmp_path, target_frame="target_0")
    assert spin_until(executor, cell.connected, 10.0)
    for k in range(11):                           # joints every 10 ms over [0, 0.1] s
        cell.send_joints(0.01 * k)
    p_cam = np.array([0.02, -0.01, 0.45])
    cell.send_point(0.055, p_cam)                 # between two TF samples
    assert spin_until(executor, lambda: len(cell.poses) == 1, 10.0)
    out = cell.poses[0]
    assert header_stamp_ns(out) == T0 + 55 * MS and out.header.frame_id == "base_link"
    # expected: every joint edge interpolated at 55 ms, chained, then the static tool frame
    edges0 = chain_tf_edges(CHAIN, _q(0.05))
    edges1 = chain_tf_edges(CHAIN, _q(0.06))
    base_T_flange = np.eye(4)
    for (_, _, A), (_, _, B) in zip(edges0, edges1, strict=True):
        base_T_flange = base_T_flange @ interpolate(55 * MS, 50 * MS, A, 60 * MS, B)
    want, _ = target_in_base(base_T_flange @ FLANGE_T_TOOL, EE_T_CAM, p_cam)
    got = np.array([out.pose.position.x, out.pose.position.y, out.pose.position.z])
    np.testing.assert_allclose(got, want, atol=1e-12)
    # not simply the pose at a sample stamp
    snap, _ = target_in_base(cell.base_T_tool(0.05), EE_T_CAM, p_cam)
    assert np.linalg.norm(got - snap) > 1e-4

    # TF out: the located target on /tf at the image stamp
    def target_tf():
        return [t for m in cell.tf_out for t in m.transforms if t.child_frame_id == "target_0"]
    assert spin_until(executor, lambda: len(target_tf()) == 1, 5.0)
    tr = target_tf()[0]
    assert tr.header.frame_id == "base_link" and header_stamp_ns(tr) == T0 + 55 * MS
    np.testing.assert_allclose(transform_to_matrix(tr)[:3, 3], want, atol=1e-12)

    # /tf_static: hand-eye and stereo extrinsic in one latched message, sent once, stamped
    # with the first image stamp (data time, not the node's clock)
    def statics():
        return {t.child_frame_id: t for m in cell.static_out for t in m.transforms}
    assert spin_until(executor, lambda: {"camera_left_optical_frame",
                                         "camera_right_optical_frame"} <= set(statics()), 5.0)
    assert len([m for m in cell.static_out                  # (the other: flange -> tool0)
                if any(t.header.frame_id == "tool0" for t in m.transforms)]) == 1
    assert {header_stamp_ns(statics()[c]) for c in (
        "camera_left_optical_frame", "camera_right_optical_frame")} == {T0 + 55 * MS}
    he = statics()["camera_left_optical_frame"]
    assert he.header.frame_id == "tool0"
    np.testing.assert_allclose(transform_to_matrix(he), EE_T_CAM, atol=1e-9)
    st = statics()["camera_right_optical_frame"]
    assert st.header.frame_id == "camera_left_optical_frame"
    np.testing.assert_allclose(transform_to_matrix(st), invert(cell.rig.right_T_left), atol=1e-9)


def test_tf_gap_and_missing_static_frame_publish_nothing(tmp_path, ros_context, executor,
                                                         namespace, spin_until):
    cell = _Cell(ros_context, executor, namespace, tmp_path, max_pose_wait_s=0.05,
                 ee_frame="tool_tip")                 # not in the tree at first
    assert spin_until(executor, cell.connected, 10.0)
    for t in (0.0, 0.01, 0.02, 0.12, 0.13):           # a 100 ms gap in the joint samples
        cell.send_joints(t)
    cell.send_point(0.01, [0.0, 0.0, 0.5])            # no tool_tip frame yet
    assert spin_until(executor, lambda: cell.node.diag.causes.get("no_robot_pose", 0) >= 1,
                      10.0)
    from tf2_msgs.msg import TFMessage  # noqa: F401

    cell.pub_static.publish(make_tf_message([("flange", "tool0", T0, FLANGE_T_TOOL),
                                             ("tool0", "tool_tip", T0, np.eye(4))]))
    buffer = cell.node.robot_poses.tf.buffer
    assert spin_until(executor, lambda: buffer.parent("tool_tip") == "tool0", 5.0)
    cell.send_point(0.07, [0.0, 0.0, 0.5])            # inside the gap: refused
    assert spin_until(executor, lambda: cell.node.diag.causes.get("no_robot_pose", 0) >= 2,
                      10.0)
    assert cell.poses == []
    cell.send_point(0.125, [0.0, 0.0, 0.5])           # after the gap: located
    assert spin_until(executor, lambda: len(cell.poses) == 1, 10.0)
    assert header_stamp_ns(cell.poses[0]) == T0 + 125 * MS


def test_bad_tf_is_counted_and_the_node_keeps_running(tmp_path, ros_context, executor,
                                                      namespace, spin_until):
    from geometry_msgs.msg import TransformStamped
    from tf2_msgs.msg import TFMessage

    cell = _Cell(ros_context, executor, namespace, tmp_path)
    assert spin_until(executor, cell.connected, 10.0)
    bad = TransformStamped()
    bad.header.frame_id = "base_link"
    bad.child_frame_id = "shoulder_link"
    bad.transform.rotation.w = 0.0                    # zero quaternion
    cell.pub_tf.publish(TFMessage(transforms=[bad]))
    assert spin_until(executor, lambda: cell.node.diag.causes.get("bad_tf", 0) >= 1, 10.0)
    for k in range(3):
        cell.send_joints(0.01 * k)
    cell.send_point(0.015, [0.0, 0.0, 0.5])
    assert spin_until(executor, lambda: len(cell.poses) == 1, 10.0)


def test_the_translation_tf_bytes_are_the_message_make_tf_message_builds():
    from rclpy.serialization import deserialize_message
    from tf2_msgs.msg import TFMessage

    from eye_in_hand.errors import ConversionError
    from eye_in_hand.ros.outputs_cdr import translation_tf_cdr

    edges = [("base_link", "target_red", 1_700_000_000_123_456_789, np.array([0.4, -0.1, 0.3])),
             ("base_link", "target_0", 5, np.array([-1e-3, 2.5, 0.0]))]
    mats = []
    for parent, child, stamp, t in edges:
        T = np.eye(4)
        T[:3, 3] = t
        mats.append((parent, child, stamp, T))
    assert deserialize_message(translation_tf_cdr(edges), TFMessage) == make_tf_message(mats)
    with pytest.raises(ConversionError, match="target_red"):
        translation_tf_cdr([("base_link", "target_red", 0, np.array([0.0, np.nan, 1.0]))])
