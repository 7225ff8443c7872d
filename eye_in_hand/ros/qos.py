"""Named QoS profiles used by every node, so publishers and subscribers always match.

=============== ============ ================= ===== ==================================
profile          reliability  durability        depth use
=============== ============ ================= ===== ==================================
``SENSOR_QOS``   best effort  volatile          5     images, camera_info, robot poses:
                                                      drop old frames, never lag behind
``RESULT_QOS``   reliable     volatile          100   target points/poses, diagnostics
``LATCHED_QOS``  reliable     transient local   1     calibration results (a late
                                                      subscriber still gets the last one)
``TARGET_POINT_  reliable     transient local   100   ``targets/<id>/point(_cov)``: a
QOS``                                                 subscription made when an id first
                                                      appears still gets its first points
``ROBOT_POSE_    best effort  volatile          500   ``ee_pose``, ``joint_states`` in
QOS``                                                 hand_eye (``/tf`` there: reliable,
                                                      the same depth): a burst of poses is
                                                      kept while the executor is busy
=============== ============ ================= ===== ==================================

A best-effort subscriber matches both reliable and best-effort publishers, so subscribing to
sensor topics with :data:`SENSOR_QOS` works with any camera driver. A transient-local
subscriber only matches transient-local publishers: subscribe to latched topics with
:data:`LATCHED_QOS` and publish them with it too.

QoS adapted to the graph or to a bag, as ``ros2 bag`` does: :func:`subscription_qos` (record or
echo a topic: match every publisher), :func:`playback_qos` and :func:`static_tf_playback_qos`
(replay a topic with what its recorded publishers offered).

This module imports rclpy.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

__all__ = ["SENSOR_QOS", "RESULT_QOS", "LATCHED_QOS", "TARGET_POINT_QOS", "ROBOT_POSE_DEPTH",
           "ROBOT_POSE_QOS", "policy_name", "subscription_qos", "LARGE_TYPES", "SMALL_DEPTH",
           "LARGE_DEPTH", "playback_qos", "static_tf_playback_qos"]

#: Sensor streams (``qos_profile_sensor_data``): best effort, volatile, keep last 5.
SENSOR_QOS: QoSProfile = QoSProfile(
    history=qos_profile_sensor_data.history,
    depth=qos_profile_sensor_data.depth,
    reliability=qos_profile_sensor_data.reliability,
    durability=qos_profile_sensor_data.durability,
)

#: Results that must not be lost: reliable, volatile, keep last 100. Reliable alone does not
#: keep a burst: a subscriber whose executor is busy (a replay at 10x, a garbage collection)
#: loses what overflows its keep-last queue, so the queue holds 100 small messages (3 s of
#: points at 30 Hz), not 10.
RESULT_QOS: QoSProfile = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=100,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)

#: Latched results (calibrations, static transforms): reliable, transient local, depth 1.
LATCHED_QOS: QoSProfile = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)

#: Per-target points (``targets/<id>/point``, ``targets/<id>/point_cov``): RESULT_QOS kept for
#: late subscribers (transient local, keep last 100). A publisher appears when its id is first
#: located and publishes that frame's point at once; hand_eye subscribes when the frame's
#: ``targets/markers`` names the id, after the point went out. Transient local delivers the
#: points it missed (up to 100: 3 s at 30 Hz, however long matching takes on a busy machine)
#: as soon as the subscription matches. A volatile subscriber matches it too (and gets only new
#: points); a transient-local subscriber does not match a volatile publisher.
TARGET_POINT_QOS: QoSProfile = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=100,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)

#: Queue depth of hand_eye's robot pose subscriptions (``ee_pose``, ``joint_states``, ``/tf``).
ROBOT_POSE_DEPTH = 500

#: Robot poses: best effort (matches reliable and best-effort publishers) but a deep queue, so
#: a burst of high-rate poses is not lost while the executor is busy.
ROBOT_POSE_QOS: QoSProfile = QoSProfile(depth=ROBOT_POSE_DEPTH,
                                        reliability=ReliabilityPolicy.BEST_EFFORT,
                                        history=HistoryPolicy.KEEP_LAST)


def policy_name(policy: Any) -> str:
    """The lower-case name of a QoS policy value (``ReliabilityPolicy.BEST_EFFORT`` ->
    ``"best_effort"``), as rosbag2 stores it."""
    return str(getattr(policy, "name", policy)).lower()


def subscription_qos(endpoints: Sequence[Any], depth: int = 100) -> QoSProfile:
    """A subscription QoS that matches every given publisher and loses as little as possible.

    Reliable when all publishers offer reliable, else best effort (compatible with both);
    transient local when all publishers offer it (so latched data is received), else volatile.

    Args:
        endpoints: ``node.get_publishers_info_by_topic(topic)``.
        depth: keep-last depth.

    Returns:
        The rclpy ``QoSProfile``.
    """
    offers = [ep.qos_profile for ep in endpoints]
    reliable = bool(offers) and all(policy_name(q.reliability) == "reliable" for q in offers)
    latched = bool(offers) and all(policy_name(q.durability) == "transient_local"
                                   for q in offers)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


#: Message types replayed at least :data:`LARGE_DEPTH` deep (a second of a 30 Hz camera); every
#: other, smaller type is offered keep-last :data:`SMALL_DEPTH`, so that a reliable subscriber
#: that is busy for a moment (a robot pose stream at 125-500 Hz) misses nothing the writer
#: already dropped.
LARGE_TYPES = frozenset({"sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage",
                         "sensor_msgs/msg/PointCloud2", "sensor_msgs/msg/LaserScan"})
SMALL_DEPTH = 1000
LARGE_DEPTH = 30


def playback_qos(offered: Sequence[Any], msgtype: str = "") -> QoSProfile:
    """The QoS to offer when replaying a topic, from what its recorded publishers offered.

    Like ``ros2 bag play``: when every recorded publisher offered the same reliability and
    durability, offer that (so a transient-local topic such as a calibration stays latched, and
    a best-effort camera stays best effort); otherwise, or when the bag has no QoS metadata,
    offer reliable, volatile, keep-last 10. A reliable offer is received by reliable and by
    best-effort (sensor-data) subscribers alike.

    Args:
        offered: the recorded profiles (:attr:`eye_in_hand.io.bags.TopicInfo.offered_qos`:
            ``reliability``, ``durability``, ``history`` as rosbag2 names them, ``depth``).

    A reliable keep-last writer drops a message that a slow subscriber has not acknowledged
    once ``depth`` newer ones are written: images and other :data:`LARGE_TYPES` are offered at
    least :data:`LARGE_DEPTH` deep (a second of a 30 Hz camera: 27 MB of 640x480 colour images),
    small messages at least :data:`SMALL_DEPTH`.

    Returns:
        An rclpy ``QoSProfile`` (keep-last; depth from the recording, at least 10; with
        ``msgtype``, at least :data:`LARGE_DEPTH` or :data:`SMALL_DEPTH`).
    """
    depth = 10
    reliability = ReliabilityPolicy.RELIABLE
    durability = DurabilityPolicy.VOLATILE
    rel = {q.reliability for q in offered}
    dur = {q.durability for q in offered}
    if offered and len(rel) == 1 and len(dur) == 1:
        if rel == {"best_effort"}:
            reliability = ReliabilityPolicy.BEST_EFFORT
        if dur == {"transient_local"}:
            durability = DurabilityPolicy.TRANSIENT_LOCAL
        depth = max([depth] + [q.depth for q in offered if q.history == "keep_last"])
    if msgtype:
        depth = max(depth, LARGE_DEPTH if msgtype in LARGE_TYPES else SMALL_DEPTH)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=reliability,
                      durability=durability)


def static_tf_playback_qos(count: int) -> QoSProfile:
    """QoS of a replayed ``/tf_static``: reliable and transient local whatever the bag
    recorded (tf2 listeners subscribe transient local and match nothing else), deep enough
    (the bag's message count, 1..1000) that a late subscriber still gets every recorded
    publisher's static transforms."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=max(1, min(int(count), 1000)),
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)
