"""ros.outputs_cdr: the live outputs serialized directly are, byte for byte, what rosbags
serializes of the messages ros.outputs builds (the content rules live there), and rclpy reads
them back as the same messages."""
from __future__ import annotations

import numpy as np
import pytest

from eye_in_hand.errors import ConversionError
from eye_in_hand.io.bags.decoding import default_typestore
from eye_in_hand.ros import outputs
from eye_in_hand.ros.outputs import RosbagsTypes, Sphere
from eye_in_hand.ros.outputs_cdr import (
    LastPointPose,
    point_cdr,
    point_pose_cdr,
    point_stamped_cdr,
    pose_array_cdr,
    sphere_markers_cdr,
    translation_tf_cdr,
)

STORE = default_typestore()
T = RosbagsTypes(STORE)
# frame ids of every length modulo 8: the padding before the doubles differs for each
FRAMES = ["", "b", "ba", "bas", "base", "base_", "base_l", "base_li", "base_link",
          "camera_left_optical_frame", "caméra"]
STAMPS = [0, 1, 1_700_000_000_123_456_789, (2 ** 31 - 1) * 10 ** 9 + 999_999_999,
          -5 * 10 ** 9 + 3]


def _ser(msg, msgtype: str) -> bytes:
    return bytes(STORE.serialize_cdr(msg, msgtype))


@pytest.mark.parametrize("frame", FRAMES)
@pytest.mark.parametrize("stamp", STAMPS)
def test_point_poses(frame, stamp):
    rng = np.random.default_rng(len(frame) + stamp % 97)
    xyz = rng.normal(size=3)
    cov = rng.normal(size=(3, 3)) * 1e-6
    pose, pose_cov = outputs.point_pose_messages(T, xyz, cov, stamp, frame)
    got = point_pose_cdr(xyz, cov, stamp, frame)
    assert got[0] == _ser(pose, "geometry_msgs/msg/PoseStamped")
    assert got[1] == _ser(pose_cov, "geometry_msgs/msg/PoseWithCovarianceStamped")


@pytest.mark.parametrize("frame", FRAMES)
@pytest.mark.parametrize("stamp", STAMPS)
def test_camera_points(frame, stamp):
    rng = np.random.default_rng(len(frame) + stamp % 89)
    xyz = rng.normal(size=3)
    cov = rng.normal(size=(3, 3)) * 1e-6
    got = point_cdr(xyz, cov, stamp, frame)
    assert got[0] == _ser(outputs.pose_with_covariance(T, xyz, cov, stamp, frame),
                          "geometry_msgs/msg/PoseWithCovarianceStamped")
    assert got[1] == _ser(outputs.point_stamped(T, xyz, stamp, frame),
                          "geometry_msgs/msg/PointStamped")
    assert point_stamped_cdr(xyz, stamp, frame) == got[1]


@pytest.mark.parametrize("frame", FRAMES)
@pytest.mark.parametrize("n", [0, 1, 2, 5])
def test_pose_arrays(frame, n):
    points = [np.array([k, -k * 0.5, 0.25 + k]) for k in range(n)]
    want = _ser(outputs.pose_array(T, points, 1_234_567_890_123, frame),
                "geometry_msgs/msg/PoseArray")
    assert pose_array_cdr(points, 1_234_567_890_123, frame) == want


@pytest.mark.parametrize("frame", FRAMES)
@pytest.mark.parametrize("n", [0, 1, 3, 7])
@pytest.mark.parametrize("lifetime_s", [0.0, 1.0, 2.75, 1e-10, 1.9999999999])
def test_sphere_markers(frame, n, lifetime_s):
    ids = ["red", "red_10", "blue_green_1", "grün", "r", "b_2", "cyan_11"]
    spheres = [Sphere(ids[k], (0.1 * k, -0.2, 1.5 + k), 0.035 * (k + 1),
                      (1.0, 0.5 * k, 0.1, 0.8)) for k in range(n)]
    want = _ser(outputs.sphere_markers(T, spheres, 987_654_321_012, frame, lifetime_s),
                "visualization_msgs/msg/MarkerArray")
    assert sphere_markers_cdr(spheres, 987_654_321_012, frame, lifetime_s) == want


@pytest.mark.parametrize("n", [0, 1, 3])
def test_translation_tf(n):
    edges = [(FRAMES[k + 3], f"target_{'é' * k}", 10 ** 9 * k + 7, np.array([k, 2.0, -1.0]))
             for k in range(n)]
    want = _ser(outputs.translation_tf_message(T, edges), "tf2_msgs/msg/TFMessage")
    assert translation_tf_cdr(edges) == want


def test_non_finite_covariances_are_carried_as_they_are():
    cov = np.array([[np.nan, 0, 0], [0, np.inf, 0], [0, 0, -np.inf]])
    pose, pose_cov = outputs.point_pose_messages(T, [0.1, 0.2, 0.3], cov, 7, "base")
    assert point_pose_cdr([0.1, 0.2, 0.3], cov, 7, "base")[1] == _ser(
        pose_cov, "geometry_msgs/msg/PoseWithCovarianceStamped")


@pytest.mark.parametrize("bad", [
    dict(lifetime_s=3e9), dict(lifetime_s=float("nan")),
    dict(rgba=(1e39, 0.0, 0.0, 1.0)), dict(rgba=(1.0, float("nan"), 0.0, 1.0)),
    dict(rgba=(1.0, 0.0, 0.0)),
])
def test_marker_values_a_message_cannot_hold_are_refused_by_both(bad):
    sphere = Sphere("a", (0, 0, 1), 0.1, bad.get("rgba", (1.0, 1.0, 1.0, 1.0)))
    life = bad.get("lifetime_s", 1.0)
    with pytest.raises(ConversionError):
        sphere_markers_cdr([sphere], 5, "base", life)
    with pytest.raises(ConversionError):
        outputs.sphere_markers(T, [sphere], 5, "base", life)


def test_the_builders_checks_apply():
    with pytest.raises(ConversionError, match="point"):
        point_pose_cdr([0.0, np.nan, 1.0], np.eye(3), 5, "base")
    with pytest.raises(ConversionError, match="stamp_ns"):
        point_pose_cdr([0.0, 0.0, 1.0], np.eye(3), 2 ** 31 * 10 ** 9, "base")
    with pytest.raises(ConversionError, match="frame_id"):
        pose_array_cdr([], 5, None)  # type: ignore[arg-type]
    with pytest.raises(ConversionError, match="two spheres"):
        sphere_markers_cdr([Sphere("a", (0, 0, 1), 0.1, (1, 1, 1, 1))] * 2, 5, "base")
    with pytest.raises(ConversionError, match="diameter"):
        sphere_markers_cdr([Sphere("a", (0, 0, 1), 0.0, (1, 1, 1, 1))], 5, "base")
    with pytest.raises(ConversionError, match="translation"):
        translation_tf_cdr([("base", "t", 5, [0, 0, np.inf])])


def test_the_last_point_pose_is_built_once_and_any_other_afresh():
    """``LastPointPose`` (hand_eye sends its first target on two topic pairs): a call equal by
    value to the last gets its bytes without building them; a call that differs in the stamp,
    the frame, one bit of the point or of the covariance, or a shape, gets
    ``point_pose_cdr``'s own bytes; a bad call raises ``point_pose_cdr``'s error and leaves
    the last answer in place."""
    rng = np.random.default_rng(7)
    xyz, cov = rng.normal(size=3), rng.normal(size=(3, 3)) * 1e-6
    last = LastPointPose()
    first = last(xyz, cov, 5, "base")
    assert first == point_pose_cdr(xyz, cov, 5, "base")
    assert last(list(xyz), cov.tolist(), 5, "base") is first
    bumped = xyz.copy()
    bumped[2] = np.nextafter(bumped[2], np.inf)
    cov_bumped = cov.copy()
    cov_bumped[1, 0] = np.nextafter(cov_bumped[1, 0], np.inf)
    for args in ((xyz, cov, 6, "base"), (xyz, cov, 5, "base_link"), (bumped, cov, 5, "base"),
                 (xyz, cov_bumped, 5, "base"), (xyz, cov.reshape(9), 5, "base"),
                 (xyz, cov, 5, "base")):
        got = last(*args)
        assert got == point_pose_cdr(*args)
    assert got is not first
    assert last(xyz, cov, 5, "base") is got
    with pytest.raises(ConversionError, match="point"):
        last([0.0, np.nan, 1.0], cov, 5, "base")
    with pytest.raises(ConversionError, match="point"):
        last(["a", 0.0, 1.0], cov, 5, "base")
    assert last(xyz, cov, 5, "base") is got


def test_rclpy_reads_them_as_the_builders_messages():
    pytest.importorskip("rclpy")
    from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
    from rclpy.serialization import deserialize_message
    from visualization_msgs.msg import MarkerArray

    R = outputs.rclpy_types()
    xyz, cov = np.array([0.3, -0.1, 0.9]), np.diag([1e-6, 2e-6, 3e-6])
    pose, pose_cov = point_pose_cdr(xyz, cov, 1_700_000_000_5, "base_link")
    want = outputs.point_pose_messages(R, xyz, cov, 1_700_000_000_5, "base_link")
    assert deserialize_message(pose, PoseStamped) == want[0]
    assert deserialize_message(pose_cov, PoseWithCovarianceStamped) == want[1]
    spheres = [Sphere("red", xyz, 0.07, (1.0, 0.0, 0.0, 1.0))]
    assert deserialize_message(sphere_markers_cdr(spheres, 42, "base_link", 1.0), MarkerArray) \
        == outputs.sphere_markers(R, spheres, 42, "base_link", 1.0)
