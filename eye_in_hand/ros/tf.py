"""TF glue: ``tf2_msgs/TFMessage`` <-> :class:`eye_in_hand.core.tf.TfBuffer`, TF QoS and topics.

``/tf`` and ``/tf_static`` are absolute topic names by ROS convention (every node of a robot
shares one tree); remap them like any topic (``--ros-args -r /tf:=tf``).

QoS as tf2_ros uses it: ``/tf`` reliable, volatile, keep last 100; ``/tf_static`` reliable,
transient local, keep last 1 on the publisher (one message carrying every static transform of
the node, re-sent whole when one changes, as ``StaticTransformBroadcaster`` does) and keep last
100 on the subscriber, so a late subscriber still receives every node's static transforms.

``tf2_msgs`` has no PyPI wheel: ``make venv`` builds it (tools/build_interfaces.py). Where it is
missing, :func:`have_tf2_msgs` is False, the nodes publish no TF, and asking for TF input
raises a :class:`ConfigError` that says so. Reading TF from a bag needs no ``tf2_msgs``
(``rosbags`` decodes it): :func:`add_tf_message` is duck-typed.
"""
from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from eye_in_hand.errors import ConfigError, ConversionError, InputError
from eye_in_hand.ros.geometry import matrix_to_transform_stamped, transform_to_matrix
from eye_in_hand.ros.stamps import header_stamp_ns

__all__ = ["TF_TOPIC", "TF_STATIC_TOPIC", "TFMESSAGE_TYPE", "have_tf2_msgs", "tf_message_class",
           "tf_qos", "tf_static_pub_qos", "tf_static_sub_qos", "add_tf_message",
           "feed_tf_message", "make_tf_message", "chain_tf_edges"]

TF_TOPIC = "/tf"
TF_STATIC_TOPIC = "/tf_static"
TFMESSAGE_TYPE = "tf2_msgs/msg/TFMessage"

_MISSING = ("tf2_msgs is not installed in this Python: run 'make venv' (it builds tf2_msgs "
            "into the venv; needs cmake and a C/C++ compiler) or source a ROS 2 install")


def have_tf2_msgs() -> bool:
    """Whether ``tf2_msgs.msg.TFMessage`` imports (system ROS or the venv build)."""
    try:  # local: whether it imports is the question (tf2_msgs has no wheel)
        from tf2_msgs.msg import TFMessage  # noqa: F401
    except ImportError:
        return False
    return True


def tf_message_class() -> Any:
    """``tf2_msgs.msg.TFMessage``.

    Raises:
        ConfigError: tf2_msgs is not installed (says how to get it).
    """
    try:  # local: tf2_msgs may be missing (no wheel), which is reported here
        from tf2_msgs.msg import TFMessage
    except ImportError as exc:
        raise ConfigError(_MISSING) from exc
    return TFMessage


def tf_qos(depth: int = 100) -> Any:
    """QoS of ``/tf`` (tf2_ros's DynamicBroadcasterQoS / DynamicListenerQoS, depth 100); a
    subscriber that must not lose a burst of late transforms asks for a deeper queue."""
    # local: rclpy is the optional [ros] extra, and offline processing imports this module
    # (feed_tf_message) without it
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(depth=depth, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def tf_static_pub_qos() -> Any:
    """QoS of a ``/tf_static`` publisher (tf2_ros's StaticBroadcasterQoS)."""
    # local: rclpy is the optional [ros] extra, and offline processing imports this module
    # (feed_tf_message) without it
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def tf_static_sub_qos() -> Any:
    """QoS of a ``/tf_static`` subscriber (tf2_ros's StaticListenerQoS)."""
    # local: rclpy is the optional [ros] extra, and offline processing imports this module
    # (feed_tf_message) without it
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def add_tf_message(buffer: Any, msg: Any, *, static: bool) -> tuple[int, list[str]]:
    """Add every transform of a TFMessage (rclpy or rosbags) to a ``TfBuffer``.

    A bad transform (non-finite values, bad quaternion, empty or looping frame ids) is skipped
    and reported; the others are added.

    Returns:
        ``(added, problems)``: the number added and one message per skipped transform.
    """
    added = 0
    problems: list[str] = []
    transforms = getattr(msg, "transforms", None)
    if transforms is None:
        return 0, ["message has no 'transforms' field (not a tf2_msgs/TFMessage)"]
    for k, tr in enumerate(transforms):
        try:
            parent = tr.header.frame_id
            child = tr.child_frame_id
            buffer.set_transform(parent, child, header_stamp_ns(tr), transform_to_matrix(tr),
                                 static=static)
            added += 1
        except (ConversionError, InputError, AttributeError) as exc:
            parent = getattr(getattr(tr, "header", None), "frame_id", "?")
            child = getattr(tr, "child_frame_id", "?")
            problems.append(f"transforms[{k}] ({parent} -> {child}): {exc}")
    return added, problems


def feed_tf_message(view: Any, msg: Any, *, static: bool, received_ns: int
                    ) -> tuple[int, list[str], bool]:
    """Add a TFMessage to the buffer behind a ``TfPoseView`` with its staleness bookkeeping:
    a dynamic transform far behind the chain's newest stamp first clears the dynamic
    transforms (a bag loop or replay), and the receive time is recorded when the chain
    advances.

    Returns:
        ``(added, problems, jumped)``: as :func:`add_tf_message`, and whether time jumped back.
    """
    jumped = False
    if not static:
        stamps = []
        for tr in getattr(msg, "transforms", None) or ():
            try:
                stamps.append(header_stamp_ns(tr))
            except (ConversionError, InputError, AttributeError):
                pass  # reported by add_tf_message
        if stamps:
            jumped = view.check_jump(max(stamps), received_ns)
    added, problems = add_tf_message(view.buffer, msg, static=static)
    if added:
        view.received(received_ns)
    return added, problems, jumped


def make_tf_message(transforms: Iterable[tuple[str, str, int, Any]]) -> Any:
    """A ``tf2_msgs.msg.TFMessage`` of ``(parent, child, stamp_ns, parent_T_child)`` tuples.

    Raises:
        ConfigError: tf2_msgs is not installed.
        ConversionError: a transform is not a finite rigid transform.
    """
    TFMessage = tf_message_class()
    return TFMessage(transforms=[
        matrix_to_transform_stamped(T, stamp_ns=int(stamp), frame_id=parent,
                                    child_frame_id=child)
        for parent, child, stamp, T in transforms])


def chain_tf_edges(chain: Any, q: Any, base_frame: str | None = None
                   ) -> list[tuple[str, str, np.ndarray]]:
    """The ``(parent, child, parent_T_child)`` edges of an arm at joint vector ``q``, as
    ``robot_state_publisher`` puts them on ``/tf``: one per joint, base to tip.

    Works with :class:`~eye_in_hand.core.kinematics.DHChain` (frames ``base_frame`` and its
    ``link_names``) and :class:`~eye_in_hand.core.kinematics.UrdfChain` (its joints' links).
    """
    frames = chain.fk_frames(q)
    if frames and isinstance(frames[0], tuple):
        return [(p, c, np.asarray(T)) for p, c, T in frames]
    base = base_frame or chain.base_frame
    dh = getattr(chain, "dh_frame", "") or base
    names = [dh, *chain.link_names]
    edges = [(names[i], names[i + 1], np.asarray(A))
             for i, A in enumerate(chain.joint_transforms(q))]
    if dh != base:   # ur_description's fixed base_link -> base (Rz(pi)) first
        edges.insert(0, (base, dh, np.asarray(chain.base_T_dh)))
    return edges
