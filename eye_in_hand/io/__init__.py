"""eye_in_hand.io: files and bags (no rclpy).

Import each module directly: :mod:`eye_in_hand.io.bags` reads and writes rosbag2 bags (sqlite3
and MCAP) with ``rosbags``; :mod:`~eye_in_hand.io.config` the hand-eye calibration file;
:mod:`~eye_in_hand.io.datasets`, :mod:`~eye_in_hand.io.pose_pairs` and
:mod:`~eye_in_hand.io.bag_samples` the hand-eye inputs; :mod:`~eye_in_hand.io.results` the
outputs of ``process``. This package imports none of them.
"""
from __future__ import annotations

__all__: list[str] = []
