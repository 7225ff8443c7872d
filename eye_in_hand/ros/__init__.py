"""rclpy glue: message conversions, QoS profiles, parameter and diagnostics helpers.

Submodules (import them directly; this package imports none of them, so that the rclpy-free
message conversions work in offline processing without ROS installed):

* the message conversions, one module per message family (no rclpy needed to decode):
  :mod:`~eye_in_hand.ros.stamps` (int ns <-> ``Time``, ``Header``),
  :mod:`~eye_in_hand.ros.images` (``Image``, ``CompressedImage`` <-> numpy),
  :mod:`~eye_in_hand.ros.camera_info` (``CameraInfo`` <->
  :class:`~eye_in_hand.core.camera.CameraModel`) and :mod:`~eye_in_hand.ros.geometry`
  (``Pose``, ``Transform``, ``Point`` <-> matrices and xyz), built on
  :mod:`~eye_in_hand.ros.fields`.
* :mod:`eye_in_hand.ros.qos` - ``SENSOR_QOS``, ``RESULT_QOS``, ``LATCHED_QOS``.
* :mod:`eye_in_hand.ros.params` - declare parameters with descriptors and load them into a
  frozen config dataclass.
* :mod:`eye_in_hand.ros.diagnostics` - counters, gauges and level rules published on
  ``diagnostics``; log-once-per-cause reporting of bad input.
* :mod:`eye_in_hand.ros.spin` - ``spin_until(executor, condition, timeout_s)``.
"""
from __future__ import annotations

__all__: list[str] = []
