"""The ``stereo_capture`` node's robot side of the ``sim`` source.

:class:`SimRobotState` and :class:`FollowedJoints` are parts of
:class:`eye_in_hand.nodes.stereo_capture.StereoCaptureNode`, built with explicit arguments, for
source ``sim`` only (the node imports this module only then: it loads the simulator).
Along the built-in trajectory, :class:`SimRobotState` publishes the arm at each pair's stamp as
the robot's driver and ``robot_state_publisher`` would. With ``sim.follow_joint_states``,
:class:`FollowedJoints` feeds the joint states received to the
:class:`~eye_in_hand.sim.frame_source.SimSource` instead.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import JointState

from eye_in_hand.errors import ConversionError
from eye_in_hand.ros.geometry import matrix_to_pose_stamped
from eye_in_hand.ros.stamps import header_stamp_ns, make_header
from eye_in_hand.ros.tf import (
    TF_STATIC_TOPIC,
    TF_TOPIC,
    chain_tf_edges,
    have_tf2_msgs,
    make_tf_message,
    tf_message_class,
    tf_qos,
    tf_static_pub_qos,
)
from eye_in_hand.sim.robot_error import reported_joints
from eye_in_hand.sim.world import World

__all__ = ["SimRobotState", "FollowedJoints"]


class SimRobotState:
    """The simulated arm at each pair's stamp (the robot pose the pair was rendered at).

    With ``sim.publish_robot_state``: ``joint_states`` and ``ee_pose`` (``base_frame`` ->
    tool); with ``sim.publish_tf`` as well (and tf2_msgs installed): the moving joints on
    ``/tf``, and the fixed ``base_frame`` -> DH base edge (with ``sim.publish_stereo_tf`` also
    the world's stereo extrinsic) on ``/tf_static``, once, at the first pair's stamp. The images
    come from the true arm; the robot reports its encoders (with noise) and the nominal arm's
    FK of them (``world.robot_error``), and ``/tf`` shows those reported joints.

    Args:
        node: the rclpy node that owns the publishers and the log.
        world: the simulated world.
        cfg: the node's parameters (``sim.seed``, ``sim.publish_robot_state``,
            ``sim.publish_tf``, ``sim.publish_stereo_tf``, ``base_frame``, ``left_frame_id``,
            ``right_frame_id``).
    """

    def __init__(self, node: Any, world: World, cfg: Mapping[str, Any]) -> None:
        self._world = world
        self._cfg = cfg
        self._encoder_rng: np.random.Generator | None = None
        self.pub_joints: Any = None
        self.pub_pose: Any = None
        self.pub_tf: Any = None
        self.pub_tf_static: Any = None
        self._static_sent = False
        if cfg["sim.publish_robot_state"]:
            self.pub_joints = node.create_publisher(JointState, "joint_states", 10)
            self.pub_pose = node.create_publisher(PoseStamped, "ee_pose", 10)
        if cfg["sim.publish_tf"]:
            self._setup_tf(node)

    def _setup_tf(self, node: Any) -> None:
        """Publishers of /tf (the arm) and /tf_static (sent with the first pair)."""
        if not have_tf2_msgs():
            node.get_logger().warning("tf2_msgs is not installed: no /tf published (run "
                                      "'make venv' to build it)")
            return
        TFMessage = tf_message_class()
        self.pub_tf = node.create_publisher(TFMessage, TF_TOPIC, tf_qos())
        # the fixed base_frame -> DH base edge (ur_description's base_link -> base) and, when
        # asked for, the true stereo extrinsic: static, once, stamped with the first pair
        self.pub_tf_static = node.create_publisher(TFMessage, TF_STATIC_TOPIC,
                                                   tf_static_pub_qos())

    def publish(self, q: np.ndarray, stamp_ns: int) -> None:
        """The robot state of a pair rendered at the true joints ``q``, stamped ``stamp_ns``."""
        if self.pub_joints is None:
            return
        js = JointState()
        js.header = make_header(stamp_ns, "")
        err = self._world.robot_error
        if self._encoder_rng is None:
            self._encoder_rng = np.random.default_rng([self._cfg["sim.seed"], err.seed, 0x5eed])
        q_rep = reported_joints(q, err, self._encoder_rng)
        js.name = list(self._world.arm.joint_names)
        js.position = [float(v) for v in q_rep]
        self.pub_joints.publish(js)
        self.pub_pose.publish(matrix_to_pose_stamped(
            self._world.arm.fk(q_rep), stamp_ns=stamp_ns, frame_id=self._cfg["base_frame"]))
        if self.pub_tf is not None:   # robot_state_publisher's view: the reported joints
            self._publish_tf(q_rep, stamp_ns)

    def _publish_tf(self, q: np.ndarray, stamp_ns: int) -> None:
        """The arm's moving joints on /tf; its fixed edge (and the stereo extrinsic with
        ``sim.publish_stereo_tf``) on /tf_static at the first pair's stamp, as
        robot_state_publisher splits them."""
        cfg = self._cfg
        edges = chain_tf_edges(self._world.arm, q, cfg["base_frame"])
        arm = self._world.arm
        base = cfg["base_frame"] or arm.base_frame
        n_fixed = 1 if (getattr(arm, "dh_frame", "") or base) != base else 0  # chain_tf_edges
        if not self._static_sent:
            static = [(p, ch, stamp_ns, T) for p, ch, T in edges[:n_fixed]]
            if cfg["sim.publish_stereo_tf"]:
                static.append((cfg["left_frame_id"], cfg["right_frame_id"], stamp_ns,
                               self._world.left_T_right))
            if static:
                self.pub_tf_static.publish(make_tf_message(static))
            self._static_sent = True
        self.pub_tf.publish(make_tf_message((p, ch, stamp_ns, T) for p, ch, T in edges[n_fixed:]))


class FollowedJoints:
    """Follow mode (``sim.follow_joint_states``): each joint state received on ``topic``
    becomes the joint vector the source renders at, stamped with the message's stamp (an
    unstamped one: stamped when published). A message without every joint of the arm, or with
    NaN or infinite positions, is reported (cause ``bad_joint_state``) and ignored.

    Args:
        node: the rclpy node that owns the subscription.
        joint_names: the arm's joints, in the order of its joint vector.
        topic: the ``JointState`` topic (``sim.joint_states_topic``).
        diag: the node's diagnostics.
        set_joints: the source's ``set_joints(q, stamp_ns)``.
    """

    def __init__(self, node: Any, joint_names: Sequence[str], topic: str, diag: Any,
                 set_joints: Callable[[np.ndarray, int | None], None]) -> None:
        self._joint_names = list(joint_names)
        self._topic = topic
        self._diag = diag
        self._set_joints = set_joints
        node.create_subscription(JointState, topic, self.on_joint_state, 10)

    def on_joint_state(self, msg: Any) -> None:
        """Hand one joint state to the source (or report why not)."""
        names = list(msg.name)
        joints = self._joint_names
        try:
            if names:
                index = {n: i for i, n in enumerate(names)}
                q = np.array([msg.position[index[n]] for n in joints], dtype=float)
            else:
                q = np.array(msg.position, dtype=float)
                if q.shape != (len(joints),):
                    raise KeyError(f"{q.size} unnamed positions")
        except (KeyError, IndexError) as exc:
            self._diag.report("bad_joint_state", f"{self._topic}: joints "
                              f"{', '.join(joints)} not all present ({exc})")
            return
        if not np.all(np.isfinite(q)):
            self._diag.report("bad_joint_state", "joint state with NaN or infinite positions")
            return
        try:
            stamp = header_stamp_ns(msg) or None   # an unstamped state: stamp when published
        except ConversionError:
            stamp = None
        self._set_joints(q, stamp)
