"""bag_recorder helpers: message definitions from Python classes, and QoS adaptation."""
from __future__ import annotations

from types import SimpleNamespace

import pytest

pytest.importorskip("rclpy")

from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from rosbags.interfaces import MessageDefinitionFormat  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from eye_in_hand.errors import BagError  # noqa: E402
from eye_in_hand.io.bags import default_typestore, types_from_definition  # noqa: E402
from eye_in_hand.nodes.bag_recorder import offered_qos  # noqa: E402
from eye_in_hand.ros.msgtypes import message_definition  # noqa: E402
from eye_in_hand.ros.qos import subscription_qos  # noqa: E402

TYPES = [
    "std_msgs/msg/String",
    "sensor_msgs/msg/Image",
    "sensor_msgs/msg/CameraInfo",
    "sensor_msgs/msg/JointState",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    "geometry_msgs/msg/PolygonStamped",
    "diagnostic_msgs/msg/DiagnosticArray",
    "stereo_msgs/msg/DisparityImage",
    "rcl_interfaces/msg/ParameterEvent",
    "std_msgs/msg/Float64MultiArray",
]


@pytest.mark.parametrize("msgtype", TYPES)
def test_generated_definition_has_the_jazzy_type_hash(msgtype: str) -> None:
    """The definition built from the Python class describes the same type as ROS 2 Jazzy's
    own .msg files: same RIHS01 hash (which covers field names, types and nesting)."""
    text = message_definition(msgtype)
    store = get_typestore(Stores.EMPTY)
    store.register(types_from_definition(msgtype, MessageDefinitionFormat.MSG, text))
    assert store.hash_rihs01(msgtype) == default_typestore().hash_rihs01(msgtype)


def test_definition_of_a_missing_type_is_an_error() -> None:
    with pytest.raises(BagError, match="not_a_pkg/msg/Nope"):
        message_definition("not_a_pkg/msg/Nope")


def _endpoint(rel: ReliabilityPolicy, dur: DurabilityPolicy, depth: int = 5) -> SimpleNamespace:
    return SimpleNamespace(qos_profile=QoSProfile(depth=depth, reliability=rel, durability=dur))


def test_subscription_qos_matches_every_publisher() -> None:
    rel, be = ReliabilityPolicy.RELIABLE, ReliabilityPolicy.BEST_EFFORT
    vol, tl = DurabilityPolicy.VOLATILE, DurabilityPolicy.TRANSIENT_LOCAL
    q = subscription_qos([_endpoint(rel, vol), _endpoint(rel, vol)])
    assert (q.reliability, q.durability) == (rel, vol)
    q = subscription_qos([_endpoint(rel, vol), _endpoint(be, vol)])
    assert q.reliability == be  # a reliable request would not match the best-effort one
    q = subscription_qos([_endpoint(rel, tl)])
    assert (q.reliability, q.durability) == (rel, tl)  # latched data is received
    q = subscription_qos([_endpoint(rel, tl), _endpoint(rel, vol)])
    assert q.durability == vol
    offers = offered_qos([_endpoint(be, tl, 3)])
    assert (offers[0].reliability, offers[0].durability, offers[0].depth) == (
        "best_effort", "transient_local", 3)
