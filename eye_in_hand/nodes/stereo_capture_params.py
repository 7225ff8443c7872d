"""The ``stereo_capture`` node's parameters (docs/simulator.md lists them).

A part of :class:`eye_in_hand.nodes.stereo_capture.StereoCaptureNode`: the node declares
:data:`NODE_PARAMETERS` at start-up; they are the keys its parameter file may hold.
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from eye_in_hand.ros.params import Param

__all__ = ["SOURCES", "NODE_PARAMETERS", "parameter_names"]

#: The frame sources (parameter ``source``).
SOURCES = ("sim", "images", "video", "v4l2")

#: The node's parameters, declared at start-up.
NODE_PARAMETERS: tuple[Param, ...] = (
    Param("source", "sim", "frame source", choices=SOURCES),
    Param("rate_hz", 30.0, "publication rate of stereo pairs (Hz)", range=(0.1, 240.0)),
    Param("left_frame_id", "camera_left_optical_frame", "frame_id of the left image"),
    Param("right_frame_id", "camera_right_optical_frame", "frame_id of the right image"),
    Param("calibration_dir", "", "folder with left.yaml + right.yaml (+ stereo.yaml) for "
          "camera_info; sim: default the world's true rig"),
    Param("left_camera_info", "", "left camera_calibration_parsers YAML (overrides "
          "calibration_dir for the left camera)"),
    Param("right_camera_info", "", "right camera_calibration_parsers YAML"),
    Param("side_by_side", False, "video/v4l2: one source holding left|right side by side"),
    Param("queue_depth", 2, "frames buffered ahead of publication (drop-oldest)",
          range=(1, 30)),
    Param("images.left", "", "images source: left folder or glob pattern"),
    Param("images.right", "", "images source: right folder or glob pattern"),
    Param("images.loop", False, "images source: start again after the last pair"),
    Param("video.left", "", "video source: left file (or the side-by-side file)"),
    Param("video.right", "", "video source: right file (empty when side_by_side)"),
    Param("video.loop", False, "video source: rewind at the end"),
    Param("v4l2.left", "0", "v4l2 source: left device index or path (or side-by-side device)"),
    Param("v4l2.right", "1", "v4l2 source: right device index or path (unused when "
          "side_by_side)"),
    Param("v4l2.width", 0, "v4l2 source: requested frame width per device (0 = driver "
          "default)", range=(0, 10000)),
    Param("v4l2.height", 0, "v4l2 source: requested frame height (0 = driver default)",
          range=(0, 10000)),
    Param("sim.world", "", "sim source: world YAML (empty = built-in default world)"),
    Param("sim.width", 0, "sim source: image width (0 = the world's)", range=(0, 8192)),
    Param("sim.height", 0, "sim source: image height (0 = the world's)", range=(0, 8192)),
    Param("sim.seed", 0, "sim source: seed of the trajectory and the noise",
          range=(0, 2**31 - 1)),
    Param("sim.duration_s", 10.0, "sim source: length of the looping trajectory (s)",
          range=(0.1, 3600.0)),
    Param("sim.noise_sigma", 1.0, "sim source: sensor noise (grey levels)", range=(0.0, 50.0)),
    Param("sim.supersample", 2, "sim source: sub-pixel rays per axis on edges", range=(1, 8)),
    Param("sim.publish_robot_state", True, "sim source: also publish joint_states and "
          "ee_pose at each pair's stamp (not when following joint states)"),
    Param("sim.publish_stereo_tf", False, "sim source with sim.publish_tf: also publish the "
          "world's true stereo extrinsic (left_frame_id -> right_frame_id) on /tf_static; off "
          "by default: hand_eye publishes the calibrated one (stereo_calibration_dir), and a "
          "transform has one publisher"),
    Param("sim.publish_tf", True, "sim source: also publish the arm as "
          "robot_state_publisher would: its joints on /tf, its fixed base edge on /tf_static "
          "(needs tf2_msgs)"),
    Param("sim.follow_joint_states", False, "sim source: render at the joint vector of the "
          "latest message on sim.joint_states_topic instead of the built-in trajectory"),
    Param("sim.joint_states_topic", "joint_states", "sim source: JointState topic followed "
          "when sim.follow_joint_states"),
    Param("base_frame", "base_link", "sim source: frame of ee_pose"),
    Param("diagnostics_period_s", 1.0, "diagnostics publication period (s)",
          range=(0.05, 60.0)),
)


def parameter_names(values: Mapping[str, Any]) -> list[str]:
    """Every parameter name the node declares (``values``: its parameters in a file, unused)."""
    return [p.name for p in NODE_PARAMETERS]
