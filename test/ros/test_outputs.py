"""The output builders give the same messages with rclpy's classes (the live nodes) and with a
rosbags type store (``process``'s output bag): serialized and read back, field for field."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

pytest.importorskip("rclpy")

from rclpy.serialization import serialize_message  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from eye_in_hand.errors import ConversionError  # noqa: E402
from eye_in_hand.ros import outputs as o  # noqa: E402
from eye_in_hand.ros.tf import have_tf2_msgs  # noqa: E402

STORE = get_typestore(Stores.ROS2_JAZZY)
STAMP = 1_700_000_000_123_456_789
SPHERES = [o.Sphere("red", np.array([0.1, 0.2, 0.3]), 0.07, (1.0, 0.0, 0.0, 0.8)),
           o.Sphere("red_1", np.array([0.1, -0.2, 0.4]), 0.05)]
COV = np.array([[1e-6, 2e-7, 0.0], [2e-7, 2e-6, 1e-7], [0.0, 1e-7, 3e-6]])
M = np.eye(4)
M[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
M[:3, 3] = [0.03, -0.06, 0.04]

CASES = {
    "visualization_msgs/msg/MarkerArray": lambda T: o.sphere_markers(T, SPHERES, STAMP, "cam",
                                                                     0.5),
    "geometry_msgs/msg/PoseArray": lambda T: o.pose_array(T, [s.xyz for s in SPHERES], STAMP,
                                                          "base_link"),
    "geometry_msgs/msg/PointStamped": lambda T: o.point_stamped(T, [1, 2, 3], STAMP, "cam"),
    "geometry_msgs/msg/PoseWithCovarianceStamped": lambda T: o.pose_with_covariance(
        T, [1, 2, 3], COV, STAMP, "base_link"),
    "geometry_msgs/msg/PoseStamped": lambda T: o.pose_stamped(T, [1, 2, 3], STAMP, "base_link"),
    "geometry_msgs/msg/TransformStamped": lambda T: o.transform_stamped(T, M, STAMP, "tool0",
                                                                        "cam"),
}
TF_CASES = {
    "tf": lambda T: o.tf_message(T, [("tool0", "cam", STAMP, M)]),
    "translation": lambda T: o.translation_tf_message(
        T, [("base_link", "target_red", STAMP, np.array([0.4, -0.1, 0.3]))]),
}


def _plain(msg):
    if dataclasses.is_dataclass(msg):
        return {f.name: _plain(getattr(msg, f.name)) for f in dataclasses.fields(msg)}
    if isinstance(msg, np.ndarray):
        return msg.tolist()
    if isinstance(msg, list):
        return [_plain(x) for x in msg]
    return msg


def _same(msgtype, build):
    live = STORE.deserialize_cdr(bytes(serialize_message(build(o.rclpy_types()))), msgtype)
    bag = build(o.RosbagsTypes(STORE))
    offline = STORE.deserialize_cdr(STORE.serialize_cdr(bag, msgtype), msgtype)
    return _plain(live), _plain(offline)


@pytest.mark.parametrize("msgtype", sorted(CASES))
def test_live_and_offline_builders_agree(msgtype):
    live, offline = _same(msgtype, CASES[msgtype])
    assert live == offline


@pytest.mark.skipif(not have_tf2_msgs(), reason="tf2_msgs not built (make venv)")
@pytest.mark.parametrize("kind", sorted(TF_CASES))
def test_live_and_offline_tf_messages_agree(kind):
    live, offline = _same("tf2_msgs/msg/TFMessage", TF_CASES[kind])
    assert live == offline


def test_rosbags_defaults_are_the_message_definitions_defaults():
    """A new rosbags message has rclpy's defaults, also the non-zero ones (Quaternion.w = 1):
    a DELETEALL marker carries the identity orientation in both."""
    T = o.RosbagsTypes(STORE)
    marker = T["visualization_msgs/msg/Marker"]()
    assert marker.pose.orientation.w == 1.0 and marker.ns == "" and len(marker.points) == 0
    with pytest.raises(TypeError, match="no field"):
        T["geometry_msgs/msg/Point"](q=1.0)


@pytest.mark.parametrize("msgtype", ["visualization_msgs/msg/MarkerArray",
                                     "visualization_msgs/msg/Marker",
                                     "geometry_msgs/msg/PoseWithCovarianceStamped",
                                     "geometry_msgs/msg/PoseArray", "tf2_msgs/msg/TFMessage",
                                     "std_msgs/msg/Header"])
def test_a_message_built_without_arguments_is_the_one_built_by_field_name(msgtype):
    """The no-argument path (fields in positionally, what the builders use) gives the same
    message, to the byte, as naming a field, and the class keeps its message type."""
    T = o.RosbagsTypes(STORE)
    _, fields = STORE.fielddefs[msgtype]
    first = fields[0][0]
    plain = T[msgtype]()
    named = T[msgtype](**{first: getattr(T[msgtype](), first)})
    assert plain.__msgtype__ == msgtype
    assert bytes(STORE.serialize_cdr(plain, msgtype)) == bytes(STORE.serialize_cdr(named, msgtype))
    marker = T["visualization_msgs/msg/Marker"]()
    assert marker.pose.orientation.w == 1.0      # the non-zero default on the positional path


def test_bad_values_are_refused_with_their_name():
    T = o.RosbagsTypes(STORE)
    with pytest.raises(ConversionError, match="point"):
        o.point_stamped(T, [0.0, np.nan, 1.0], STAMP, "cam")
    with pytest.raises(ConversionError, match="diameter"):
        o.sphere_markers(T, [o.Sphere("a", np.zeros(3), 0.0)], STAMP, "cam")
    with pytest.raises(ConversionError, match="two spheres"):
        o.sphere_markers(T, [SPHERES[0], SPHERES[0]], STAMP, "cam")
