"""A robot driver stand-in for the live-cell tests, run as its own process (as a driver is).

Publishes, in the namespace given, ``joint_states`` (the encoders: the true joints with the
simulator's default robot error's encoder noise) at 250 Hz, and at 125 Hz
``sim/true_joint_states`` (what the simulated camera renders) and either ``/tf``
(robot_state_publisher's view of the reported joints) or ``ee_pose``, each stamped with its
control cycle's time. The control cycle is a fixed
4 ms grid: when the process is late (a busy machine), the missed cycles go out together, late,
each with its own stamp, never leaving a gap in the stamps.

``eye_to_hand``: a fixed camera watches a board carried by the flange. The camera still
renders the world's views (what it sees depends only on where the board is relative to it),
and ``ee_pose`` is the flange pose that holds the board there: :func:`eye_to_hand_flange` of
the reported joints (so it carries the arm's kinematic and encoder error, as ``/tf`` would).

The arm holds stop 0; each integer published on ``sim/go_to_stop`` (std_msgs/Int32) starts a
smooth 1 s joint motion to that stop of ``calibration_poses(world, stops, seed)``, where it then
stays. ``sim/arrived`` (std_msgs/Int32, latched) says which stop the arm stands at.

Usage: python robot_driver_standin.py NAMESPACE {tf,ee_pose,eye_to_hand} STOPS SEED WIDTH HEIGHT
"""
from __future__ import annotations

import sys

import numpy as np
import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Int32

from eye_in_hand.ros.geometry import matrix_to_pose_stamped
from eye_in_hand.ros.qos import LATCHED_QOS, SENSOR_QOS
from eye_in_hand.ros.stamps import make_header
from eye_in_hand.ros.tf import TF_TOPIC, chain_tf_edges, make_tf_message, tf_message_class, tf_qos
from eye_in_hand.sim import World
from eye_in_hand.sim.robot_error import reported_joints
from eye_in_hand.sim.scenarios import calibration_poses

MOVE_S = 1.0
PERIOD_NS = 4_000_000
#: eye_to_hand: the fixed camera (base_T_cam, the X to find) and the board on the flange.
EYE_TO_HAND_BASE_T_CAM = ((2.3, 0.2, -0.3), (0.9, -0.2, 0.7))      # (rotvec, t)
EYE_TO_HAND_EE_T_BOARD = ((0.1, 3.0415926535897933, 0.2), (0.01, 0.02, 0.1))


def eye_to_hand_transforms() -> tuple[np.ndarray, np.ndarray]:
    """``(base_T_cam, ee_T_board)`` of the eye-to-hand cell."""
    from eye_in_hand.core.transforms import from_rotvec

    return (from_rotvec(*EYE_TO_HAND_BASE_T_CAM), from_rotvec(*EYE_TO_HAND_EE_T_BOARD))


def eye_to_hand_flange(world: World, base_T_eyecam: np.ndarray) -> np.ndarray:
    """The flange pose that shows the fixed camera the board as the world's camera at
    ``base_T_eyecam`` sees the world's board."""
    base_T_cam, ee_T_board = eye_to_hand_transforms()
    return base_T_cam @ np.linalg.inv(base_T_eyecam) @ world.base_T_board @ \
        np.linalg.inv(ee_T_board)


def smoothstep(s: float) -> float:
    return s * s * (3.0 - 2.0 * s)


class Driver(Node):
    def __init__(self, world: World, stops: list[np.ndarray], robot: str, namespace: str):
        super().__init__("robot_driver", namespace=namespace)
        self.world, self.stops = world, stops
        self.rng = np.random.default_rng(7)
        self.names = list(world.arm.joint_names)
        self.pub_js = self.create_publisher(JointState, "joint_states", SENSOR_QOS)
        self.pub_true = self.create_publisher(JointState, "sim/true_joint_states", 10)
        self.eye_to_hand = robot == "eye_to_hand"
        self.pub_pose = self.create_publisher(PoseStamped, "ee_pose", SENSOR_QOS) \
            if robot in ("ee_pose", "eye_to_hand") else None
        # a deep history: a reliable keep-last writer overwrites what a busy subscriber has not
        # acknowledged yet, which would show as a gap in the robot's motion
        self.pub_tf = self.create_publisher(tf_message_class(), TF_TOPIC, tf_qos(500)) \
            if robot == "tf" else None
        self.pub_arrived = self.create_publisher(Int32, "sim/arrived", LATCHED_QOS)
        self.create_subscription(Int32, "sim/go_to_stop", self._go, 10)
        now = self.get_clock().now().nanoseconds
        self.stop, self.prev, self.leg_start_ns = 0, 0, now - int(MOVE_S * 1e9)
        self.arrived = -1
        self.cycle = 0
        self.next_ns = now
        self.create_timer(PERIOD_NS / 1e9, self._tick)

    def _go(self, msg: Int32) -> None:
        if msg.data != self.stop and 0 <= msg.data < len(self.stops):
            self.prev, self.stop = self.stop, msg.data
            self.leg_start_ns = self.next_ns

    def q_true(self, stamp_ns: int) -> tuple[np.ndarray, bool]:
        s = (stamp_ns - self.leg_start_ns) / 1e9 / MOVE_S
        q1 = np.asarray(self.stops[self.stop], float)
        if s >= 1.0:
            return q1, True
        q0 = np.asarray(self.stops[self.prev], float)
        return q0 + (q1 - q0) * smoothstep(max(s, 0.0)), False

    def _tick(self) -> None:
        now = self.get_clock().now().nanoseconds
        while self.next_ns <= now:
            self._publish(self.next_ns)
            self.next_ns += PERIOD_NS

    def _publish(self, stamp: int) -> None:
        q, still = self.q_true(stamp)
        header = make_header(stamp, "")
        q_rep = reported_joints(q, self.world.robot_error, self.rng)
        self.pub_js.publish(JointState(header=header, name=self.names,
                                       position=[float(v) for v in q_rep]))
        self.cycle += 1
        if self.cycle % 2:
            return            # the rest at 125 Hz (a /tf message costs ~1-6 ms in Python)
        self.pub_true.publish(JointState(header=header, name=self.names,
                                         position=[float(v) for v in q]))
        if self.pub_tf is not None:
            edges = chain_tf_edges(self.world.arm, q_rep, "base_link")
            self.pub_tf.publish(make_tf_message((p, c, stamp, T) for p, c, T in edges))
        if self.pub_pose is not None:
            T = self.world.arm.fk(q_rep)
            if self.eye_to_hand:
                T = eye_to_hand_flange(self.world, T @ self.world.ee_T_cam)
            self.pub_pose.publish(matrix_to_pose_stamped(T, stamp_ns=stamp,
                                                         frame_id="base_link"))
        if still and self.arrived != self.stop:
            self.arrived = self.stop
            self.pub_arrived.publish(Int32(data=self.stop))


def main() -> None:
    namespace, robot, n, seed, width, height = sys.argv[1:7]
    world = World.default().with_image_size(int(width), int(height))
    stops = calibration_poses(world, int(n), seed=int(seed))
    rclpy.init()
    node = Driver(world, stops, robot, namespace)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
