"""eye_in_hand: eye-in-hand stereo target localization and calibration for ROS 2.

Subpackages:
    core      pure numerics (numpy/scipy/OpenCV), never rclpy or message types
    io        files and bags (rosbags), no rclpy
    sim       synthetic eye-in-hand world with ground truth
    ros       rclpy glue: message conversions, QoS, parameters
    nodes     one module per ROS 2 node
    commands  the ``eye-in-hand`` sub-commands
"""
from __future__ import annotations

__version__ = "0.1.0"
__all__ = ["__version__"]
