"""eye_in_hand.io: files and bags (no rclpy).

:mod:`eye_in_hand.io.bags` reads and writes rosbag2 bags (sqlite3 and MCAP) with ``rosbags``.
"""
from __future__ import annotations

from eye_in_hand.io.bags import (
    BagInfo,
    BagMessage,
    BagWriter,
    OfferedQos,
    TopicInfo,
    bag_info,
    deserialize,
    iter_decoded,
    iter_messages,
    require_topics,
    serialize,
    typestore_for,
)

__all__ = [
    "BagInfo",
    "BagMessage",
    "BagWriter",
    "OfferedQos",
    "TopicInfo",
    "bag_info",
    "deserialize",
    "iter_decoded",
    "iter_messages",
    "require_topics",
    "serialize",
    "typestore_for",
]
