"""Every target through the live nodes (issue #12), in process.

detect_triangulate -> hand_eye with two targets of different colours: per-target topics in the
camera and base frames, the per-frame PoseArray and MarkerArrays, a target missing from one
frame, the first-target topics unchanged; hand_eye on its own: dropped targets counted by
reason, and eye-to-hand localization without any robot pose.
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest

pytest.importorskip("rclpy")

from geometry_msgs.msg import PointStamped, PoseArray, PoseStamped, PoseWithCovarianceStamped  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402
from visualization_msgs.msg import Marker, MarkerArray  # noqa: E402

from eye_in_hand.core.camera import CameraModel, StereoRig  # noqa: E402
from eye_in_hand.core.localization import target_in_base  # noqa: E402
from eye_in_hand.core.transforms import from_rotvec, interpolate  # noqa: E402
from eye_in_hand.io.config import HandEyeCalibration, save_hand_eye  # noqa: E402
from eye_in_hand.nodes.detect_triangulate import DetectTriangulateNode  # noqa: E402
from eye_in_hand.nodes.hand_eye import HandEyeNode  # noqa: E402
from eye_in_hand.ros.geometry import matrix_to_pose_stamped
from eye_in_hand.ros.images import numpy_to_image
from eye_in_hand.ros.markers import Sphere, sphere_marker_array  # noqa: E402
from eye_in_hand.ros.outputs import pose_with_covariance, rclpy_types  # noqa: E402
from eye_in_hand.ros.qos import RESULT_QOS, SENSOR_QOS  # noqa: E402
from eye_in_hand.ros.stamps import header_stamp_ns
from eye_in_hand.sim.sphere import render_sphere  # noqa: E402

W, H = 640, 360
K = np.array([[450.0, 0.0, 320.0], [0.0, 452.0, 180.0], [0.0, 0.0, 1.0]])
CAM = "camera_left_optical_frame"
T0 = 1_700_000_000_000_000_000
PERIOD_NS = 50_000_000
EE_T_CAM = from_rotvec([0.1, -0.2, 0.05], [0.03, -0.05, 0.08])
COV_X = np.diag([1e-6, 2e-6, 3e-6, 1e-5, 2e-5, 3e-5])
#: target name -> (true centre in the left optical frame, BGR colour)
TARGETS = {"red": (np.array([0.05, -0.02, 0.40]), (30, 30, 200)),
           "green": (np.array([-0.06, 0.03, 0.45]), (40, 200, 40))}


def _rig() -> StereoRig:
    left = CameraModel(K, [-0.2, 0.08, 0.0, 0.0, 0.0], W, H, name="left")
    right = CameraModel(K, [-0.19, 0.07, 0.0, 0.0, 0.0], W, H, name="right")
    R = cv2.Rodrigues(np.array([0.005, -0.01, 0.0]))[0]
    return StereoRig(left, right, R, [-0.06, 0.0, 0.0]).rectified()


RIG = _rig()


def _render(names) -> tuple[np.ndarray, np.ndarray]:
    out = []
    for cam, T in ((RIG.left, np.eye(4)), (RIG.right, RIG.right_T_left)):
        img = np.full((H, W, 3), (90, 110, 100), np.uint8)
        for n in names:
            x, bgr = TARGETS[n]
            render_sphere(img, cam, T[:3, :3] @ x + T[:3, 3], 0.02, bgr)
        out.append(img)
    return out[0], out[1]


BOTH = _render(["red", "green"])
RED_ONLY = _render(["red"])


def _robot_pose(stamp_ns: int) -> np.ndarray:
    t = (stamp_ns - T0) / 1e9
    return from_rotvec([0.0, 0.3 * np.sin(t), 0.2 * t], [0.4 + 0.1 * t, 0.1, 0.5])


def _hand_eye_file(tmp_path, setup="eye_in_hand", transform=EE_T_CAM, cov=COV_X):
    path = tmp_path / f"{setup}.yaml"
    save_hand_eye(path, HandEyeCalibration(
        setup=setup, parent_frame="tool0" if setup == "eye_in_hand" else "base_link",
        child_frame=CAM, transform=transform, method="refined", covariance=cov,
        sample_count=15))
    return path


def _collect(node: Node, msg_type, topic: str) -> list:
    out: list = []
    node.create_subscription(msg_type, topic, out.append, RESULT_QOS)
    return out


def _by_stamp(msgs) -> dict[int, object]:
    return {header_stamp_ns(m if not hasattr(m, "markers") else m.markers[0]): m for m in msgs}


def test_two_targets_through_detect_triangulate_and_hand_eye(tmp_path, ros_context, executor,
                                                             namespace, spin_until):
    RIG.save(tmp_path / "calib")
    detect = DetectTriangulateNode(context=ros_context, namespace=namespace, parameter_overrides=[
        Parameter("calibration_dir", value=str(tmp_path / "calib")),
        Parameter("frame_id", value=CAM), Parameter("sync.slop_s", value=0.0),
        Parameter("target_names", value=["red", "green"]),
        Parameter("targets.green.lower", value=[45, 120, 70]),
        Parameter("targets.green.upper", value=[75, 255, 255])])
    hand_eye = HandEyeNode(context=ros_context, namespace=namespace, parameter_overrides=[
        Parameter("hand_eye_file", value=str(_hand_eye_file(tmp_path))),
        Parameter("robot_sigma_pos_m", value=0.0), Parameter("robot_sigma_rot_rad", value=0.0),
        Parameter("discovery_period_s", value=0.1)])
    io = Node("io", context=ros_context, namespace=namespace)
    for n in (detect, hand_eye, io):
        executor.add_node(n)
    pub_l = io.create_publisher(Image, "left/image_raw", SENSOR_QOS)
    pub_r = io.create_publisher(Image, "right/image_raw", SENSOR_QOS)
    pub_ee = io.create_publisher(PoseStamped, "ee_pose", SENSOR_QOS)
    cam_cov = {n: _collect(io, PoseWithCovarianceStamped, f"targets/{n}/point_cov")
               for n in TARGETS}
    cam_markers = _collect(io, MarkerArray, "targets/markers")
    poses = {n: _collect(io, PoseStamped, f"target/{n}/pose") for n in TARGETS}
    pose_covs = {n: _collect(io, PoseWithCovarianceStamped, f"target/{n}/pose_cov")
                 for n in TARGETS}
    arrays = _collect(io, PoseArray, "target/poses")
    base_markers = _collect(io, MarkerArray, "target/markers")
    first = _collect(io, PoseStamped, "target/pose")
    first_point = _collect(io, PointStamped, "target/point")
    # hand_eye found both per-target topics in the graph before any frame (none is lost) and
    # offers target/<id>/pose from then on, so its subscribers match before the first frame
    assert spin_until(executor, lambda: set(hand_eye.targets.subs) == set(TARGETS)
                      and pub_l.get_subscription_count() and pub_ee.get_subscription_count()
                      and all(hand_eye.count_publishers(f"targets/{n}/point_cov") for n in
                              TARGETS) and io.count_publishers("target/poses")
                      and all(io.count_publishers(f"target/{n}/pose") for n in TARGETS), 15.0)
    frames = [BOTH, RED_ONLY, BOTH]           # green leaves the view in the middle frame
    stamps = [T0 + k * PERIOD_NS for k in range(len(frames))]
    for stamp, (left, right) in zip(stamps, frames, strict=True):
        for dt in (-10_000_000, 10_000_000):   # robot poses bracket the image stamp
            pub_ee.publish(matrix_to_pose_stamped(_robot_pose(stamp + dt), stamp_ns=stamp + dt,
                                                  frame_id="base_link"))
        pub_l.publish(numpy_to_image(left, "bgr8", stamp_ns=stamp, frame_id=CAM))
        pub_r.publish(numpy_to_image(right, "bgr8", stamp_ns=stamp, frame_id=CAM))
        assert spin_until(executor, lambda stamp=stamp: len(arrays) == stamps.index(stamp) + 1,
                          15.0), (
            detect.diag.snapshot().counters, hand_eye.diag.snapshot().counters,
            hand_eye.diag.causes)
    spin_until(executor, lambda: False, 0.2)    # anything extra would arrive now

    # camera side: every target on its own topics, one marker array per frame
    assert [len(cam_cov[n]) for n in ("red", "green")] == [3, 2]
    assert [header_stamp_ns(m.markers[0]) for m in cam_markers] == stamps
    for m in cam_markers:
        assert m.markers[0].action == Marker.DELETEALL
        assert all(x.header.frame_id == CAM for x in m.markers)
        spheres = {x.ns: x for x in m.markers[1:]}
        for n, x in spheres.items():
            assert x.type == Marker.SPHERE and x.scale.x == pytest.approx(0.04)
            p = np.array([x.pose.position.x, x.pose.position.y, x.pose.position.z])
            assert np.linalg.norm(p - TARGETS[n][0]) < 2e-3
        assert spheres["red"].color.r > 0.9 and spheres["red"].color.g < 0.1
        if "green" in spheres:
            assert spheres["green"].color.g > 0.9 and spheres["green"].color.r < 0.1
    assert [sorted(x.ns for x in m.markers[1:]) for m in cam_markers] == [
        ["green", "red"], ["red"], ["green", "red"]]

    # base side: each target's pose from its own point and covariance, at its image stamp
    for n in TARGETS:
        cams = _by_stamp(cam_cov[n])
        assert [header_stamp_ns(p) for p in poses[n]] == sorted(cams)
        for pose, pcov in zip(poses[n], pose_covs[n], strict=True):
            stamp = header_stamp_ns(pose)
            assert header_stamp_ns(pcov) == stamp and pose.header.frame_id == "base_link"
            c = cams[stamp]
            p_cam = np.array([c.pose.pose.position.x, c.pose.pose.position.y,
                              c.pose.pose.position.z])
            cov_cam = np.asarray(c.pose.covariance).reshape(6, 6)[:3, :3]
            base_T_ee = interpolate(stamp, stamp - 10_000_000, _robot_pose(stamp - 10_000_000),
                                    stamp + 10_000_000, _robot_pose(stamp + 10_000_000))
            want, want_cov = target_in_base(base_T_ee, EE_T_CAM, p_cam, cov_cam=cov_cam,
                                            cov_hand_eye=COV_X)
            got = np.array([pose.pose.position.x, pose.pose.position.y, pose.pose.position.z])
            assert np.allclose(got, want, atol=1e-9)
            got_cov = np.asarray(pcov.pose.covariance).reshape(6, 6)[:3, :3]
            assert np.allclose(got_cov, want_cov, rtol=1e-9, atol=1e-18)
            truth, _ = target_in_base(base_T_ee, EE_T_CAM, TARGETS[n][0])
            assert np.linalg.norm(got - truth) < 3e-3

    # per frame: a PoseArray and spheres in the base frame, in the same order, image stamps
    assert [header_stamp_ns(a) for a in arrays] == stamps
    assert [header_stamp_ns(m.markers[0]) for m in base_markers] == stamps
    for a, m in zip(arrays, base_markers, strict=True):
        stamp = header_stamp_ns(a)
        assert a.header.frame_id == "base_link" and m.markers[0].action == Marker.DELETEALL
        ids = [x.ns for x in m.markers[1:]]
        assert len(a.poses) == len(ids) and all(x.header.frame_id == "base_link"
                                                for x in m.markers)
        for pose, x in zip(a.poses, m.markers[1:], strict=True):
            want = _by_stamp(poses[x.ns])[stamp].pose.position
            assert (pose.position.x, pose.position.y, pose.position.z) == (
                want.x, want.y, want.z) == (x.pose.position.x, x.pose.position.y,
                                            x.pose.position.z)
    assert [len(a.poses) for a in arrays] == [2, 1, 2]

    # the first target's topics are unchanged: target/point and target/pose carry red
    assert [header_stamp_ns(p) for p in first] == stamps == [header_stamp_ns(p)
                                                             for p in first_point]
    reds = _by_stamp(poses["red"])
    for p in first:
        assert p.pose.position == reds[header_stamp_ns(p)].pose.position

    # ledgers: every located target published and located in the base frame, none dropped
    d, h = detect.diag.snapshot().counters, hand_eye.diag.snapshot().counters
    assert d["targets_located"] == d["target_points_published"] == 5
    assert d["marker_frames"] == 3 and d["targets_refused"] == 0
    assert h["target_points"] == h["target_points_received"] == h["target_poses_published"] == 5
    assert h["targets_rejected"] == 0 and h["target_frames_published"] == 3


class _Feed:
    """Plays detect_triangulate's part: targets/markers and targets/<id>/point_cov."""

    def __init__(self, ros_context, executor, namespace, overrides, cli_args=None):
        self.node = HandEyeNode(context=ros_context, namespace=namespace,
                                parameter_overrides=[Parameter(k, value=v)
                                                     for k, v in overrides.items()],
                                cli_args=cli_args)
        self.io = Node("feed", context=ros_context, namespace=namespace, cli_args=cli_args)
        executor.add_node(self.node)
        executor.add_node(self.io)
        self.pub_markers = self.io.create_publisher(MarkerArray, "targets/markers", RESULT_QOS)
        self.pub_cov = {n: self.io.create_publisher(PoseWithCovarianceStamped,
                                                    f"targets/{n}/point_cov", RESULT_QOS)
                        for n in ("a", "b")}
        self.pub_ee = self.io.create_publisher(PoseStamped, "ee_pose", SENSOR_QOS)
        self.poses = {n: _collect(self.io, PoseStamped, f"target/{n}/pose") for n in "ab"}
        self.covs = {n: _collect(self.io, PoseWithCovarianceStamped, f"target/{n}/pose_cov")
                     for n in "ab"}
        self.arrays = _collect(self.io, PoseArray, "target/poses")
        self.first = _collect(self.io, PoseStamped, "target/pose")

    def ready(self, executor, spin_until) -> bool:
        return spin_until(executor, lambda: set(self.node.targets.subs) >= {"a", "b"}
                          and self.pub_markers.get_subscription_count() > 0
                          and self.io.count_publishers("target/poses") > 0, 15.0)

    def frame(self, stamp, points: dict, listed=None, covs=None):
        """Publish the points (id -> (3,)) and a marker array listing ``listed`` ids."""
        for tid, p in points.items():
            cov = (covs or {}).get(tid, np.diag([1e-8, 2e-8, 4e-7]))
            self.pub_cov[tid].publish(pose_with_covariance(rclpy_types(), p, cov, stamp, CAM))
        listed = list(points) if listed is None else listed
        self.pub_markers.publish(sphere_marker_array(
            [Sphere(t, points.get(t, np.zeros(3)), 0.04) for t in listed], stamp_ns=stamp,
            frame_id=CAM))


def test_eye_to_hand_localizes_every_target_without_a_robot_pose(
        tmp_path, ros_context, executor, namespace, spin_until):
    base_T_cam = from_rotvec([2.0, 0.3, -0.4], [0.8, -0.3, 1.1])
    cov_x = np.diag([4e-6, 1e-6, 9e-6, 2e-5, 1e-5, 3e-5])
    feed = _Feed(ros_context, executor, namespace, {
        "hand_eye_file": str(_hand_eye_file(tmp_path, "eye_to_hand", base_T_cam, cov_x)),
        "robot_pose_source": "ee_pose"})
    assert feed.node.eye_to_hand
    assert feed.ready(executor, spin_until)
    assert feed.node.count_subscribers("ee_pose") == 0     # no robot pose is listened to
    pts = {"a": np.array([0.02, -0.01, 0.45]), "b": np.array([-0.1, 0.05, 0.7])}
    covs = {"a": np.diag([1e-8, 2e-8, 4e-7]), "b": np.diag([3e-8, 1e-8, 9e-7])}
    feed.frame(T0, pts, covs=covs)
    # the first-target topic too: target/point (+ _cov) -> target/pose
    from eye_in_hand.ros.geometry import xyz_to_point_stamped
    pub_pc = feed.io.create_publisher(PoseWithCovarianceStamped, "target/point_cov", RESULT_QOS)
    pub_p = feed.io.create_publisher(PointStamped, "target/point", RESULT_QOS)
    assert spin_until(executor, lambda: pub_p.get_subscription_count() > 0
                      and pub_pc.get_subscription_count() > 0, 10.0)
    pub_pc.publish(pose_with_covariance(rclpy_types(), pts["a"], covs["a"], T0, CAM))
    pub_p.publish(xyz_to_point_stamped(pts["a"], stamp_ns=T0, frame_id=CAM))
    assert spin_until(executor, lambda: len(feed.arrays) == 1 and len(feed.first) == 1
                      and all(len(feed.covs[n]) == 1 for n in "ab"), 10.0)
    R = base_T_cam[:3, :3]
    for n in "ab":
        q = R @ pts[n]
        want = q + base_T_cam[:3, 3]
        J = np.hstack([np.eye(3), -np.array([[0, -q[2], q[1]], [q[2], 0, -q[0]],
                                             [-q[1], q[0], 0]])])
        want_cov = R @ covs[n] @ R.T + J @ cov_x @ J.T      # camera rotated + hand-eye
        p = feed.poses[n][0].pose.position
        assert np.allclose([p.x, p.y, p.z], want, atol=1e-12)
        got_cov = np.asarray(feed.covs[n][0].pose.covariance).reshape(6, 6)[:3, :3]
        assert np.allclose(got_cov, want_cov, rtol=1e-9, atol=1e-18)
        assert header_stamp_ns(feed.poses[n][0]) == T0
    assert header_stamp_ns(feed.arrays[0]) == T0 and len(feed.arrays[0].poses) == 2
    # the covariance is honest: simulated errors of the camera point and of base_T_cam (the
    # rotation perturbed on the left, as hand_eye.yaml says) give NEES ~ 3 and 95 % coverage
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(12)
    n_mc = 20000
    got_cov = np.asarray(feed.covs["b"][0].pose.covariance).reshape(6, 6)[:3, :3]
    p_true = R @ pts["b"] + base_T_cam[:3, 3]
    dx = rng.multivariate_normal(np.zeros(6), cov_x, n_mc)
    dp = rng.multivariate_normal(np.zeros(3), covs["b"], n_mc)
    Rk = Rotation.from_rotvec(dx[:, 3:]).as_matrix() @ R             # (n, 3, 3)
    errs = np.einsum("nij,nj->ni", Rk, pts["b"] + dp) + base_T_cam[:3, 3] + dx[:, :3] - p_true
    nees = np.einsum("ij,jk,ik->i", errs, np.linalg.inv(got_cov), errs)
    assert 2.85 < nees.mean() < 3.15, nees.mean()
    assert 0.94 < np.mean(nees < 7.8147) < 0.96            # chi2(3) 95 % quantile
    p0 = feed.first[0].pose.position
    assert np.allclose([p0.x, p0.y, p0.z], R @ pts["a"] + base_T_cam[:3, 3], atol=1e-12)
    h = feed.node.diag.snapshot().counters
    assert h["robot_poses"] == 0 and h["targets_rejected"] == 0 and h["rejected"] == 0


def test_dropped_targets_are_counted_by_reason(tmp_path, ros_context, executor, namespace,
                                              spin_until):
    feed = _Feed(ros_context, executor, namespace, {
        "hand_eye_file": str(_hand_eye_file(tmp_path)), "max_target_wait_s": 0.05,
        "max_pose_wait_s": 0.05, "max_targets": 2, "target_frame_prefix": ""})
    assert feed.ready(executor, spin_until)
    node = feed.node
    for k in range(11):           # robot poses over [0, 100] ms
        s = T0 + k * 10_000_000
        feed.pub_ee.publish(matrix_to_pose_stamped(_robot_pose(s), stamp_ns=s,
                                                   frame_id="base_link"))
    assert spin_until(executor, lambda: node.diag.counter("robot_poses") == 11, 10.0)
    pts = {"a": np.array([0.0, 0.0, 0.5]), "b": np.array([0.1, 0.0, 0.6])}
    feed.frame(T0 + 20_000_000, pts)                                  # both located
    feed.frame(T0 + 30_000_000, {"a": pts["a"]}, listed=["a", "b"])   # b's point lost
    feed.frame(T0 + 40_000_000, pts, listed=["a", "b", "c", "9bad"])  # c: over max_targets
    feed.frame(T0 + 500_000_000, pts)                                 # no robot pose there
    assert spin_until(executor, lambda: node.diag.counter("target_frames_published") == 4
                      and not node.pipeline.frames, 10.0), node.diag.snapshot().counters
    c = node.diag.snapshot().counters
    refused = {k: v for k, v in c.items() if k.startswith("target_refused.") and v}
    assert refused == {"target_refused.no_point": 1, "target_refused.too_many_targets": 1,
                       "target_refused.bad_target_id": 1,
                       "target_refused.no_newer_pose": 2}, refused
    assert c["targets_rejected"] == sum(refused.values()) == 5
    assert c["target_points"] == 2 + 2 + 4 + 2
    assert c["target_points"] == c["target_poses_published"] + c["targets_rejected"]
    assert spin_until(executor, lambda: len(feed.arrays) == 4 and len(feed.poses["b"]) == 2,
                      10.0)
    assert [len(a.poses) for a in feed.arrays] == [2, 1, 2, 0]
    assert [header_stamp_ns(p) for p in feed.poses["b"]] == [T0 + 20_000_000, T0 + 40_000_000]
    # b's pose uses b's own point and covariance, not a's
    want, _ = target_in_base(interpolate(T0 + 20_000_000, T0 + 20_000_000,
                                         _robot_pose(T0 + 20_000_000), T0 + 30_000_000,
                                         _robot_pose(T0 + 30_000_000)), EE_T_CAM, pts["b"])
    p = feed.poses["b"][0].pose.position
    assert np.allclose([p.x, p.y, p.z], want, atol=1e-9)
    assert "no_robot_pose" in node.diag.causes and "target_no_point" in node.diag.causes


def test_undecodable_target_lists_and_points_are_reported_and_nothing_else_lost(
        tmp_path, ros_context, executor, namespace, spin_until):
    feed = _Feed(ros_context, executor, namespace, {
        "hand_eye_file": str(_hand_eye_file(tmp_path)), "max_target_wait_s": 0.05,
        "target_frame_prefix": ""})
    assert feed.ready(executor, spin_until)
    node = feed.node
    for k in range(11):
        s = T0 + k * 10_000_000
        feed.pub_ee.publish(matrix_to_pose_stamped(_robot_pose(s), stamp_ns=s,
                                                   frame_id="base_link"))
    # the node takes these topics as bytes and decodes them itself
    feed.pub_markers.publish(b"\x00\x01\x00\x00\x09")
    feed.pub_cov["a"].publish(b"\x00\x01\x00\x00")
    pts = {"a": np.array([0.0, 0.0, 0.5]), "b": np.array([0.1, 0.0, 0.6])}
    feed.frame(T0 + 20_000_000, pts)
    assert spin_until(executor, lambda: len(feed.arrays) == 1 and len(feed.poses["b"]) == 1
                      and node.diag.causes.get("bad_target_point") == 1, 10.0)
    assert node.diag.causes.get("bad_markers") == 1
    c = node.diag.snapshot().counters
    assert c["target_frames"] == 2 and c["target_points_received"] == 3
    assert [len(a.poses) for a in feed.arrays] == [2]


def test_eye_to_hand_tf_one_child_frame_per_target(tmp_path, ros_context, executor, namespace,
                                                   spin_until):
    from eye_in_hand.ros.geometry import transform_to_matrix
    from eye_in_hand.ros.tf import have_tf2_msgs, tf_qos, tf_static_sub_qos

    if not have_tf2_msgs():
        pytest.skip("tf2_msgs not built (make venv)")
    from tf2_msgs.msg import TFMessage

    base_T_cam = from_rotvec([2.0, 0.3, -0.4], [0.8, -0.3, 1.1])
    remap = ["--ros-args", "-r", f"/tf:={namespace}/tf", "-r",
             f"/tf_static:={namespace}/tf_static"]
    feed = _Feed(ros_context, executor, namespace, {
        "hand_eye_file": str(_hand_eye_file(tmp_path, "eye_to_hand", base_T_cam, None))},
        cli_args=remap)
    tf_out, static_out = [], []
    feed.io.create_subscription(TFMessage, "/tf", tf_out.append, tf_qos())
    feed.io.create_subscription(TFMessage, "/tf_static", static_out.append, tf_static_sub_qos())
    assert feed.ready(executor, spin_until)
    pub_tf = feed.node.tf_output.pub_tf
    assert spin_until(executor, lambda: pub_tf.get_subscription_count() > 0, 10.0)
    from geometry_msgs.msg import PointStamped

    from eye_in_hand.ros.geometry import xyz_to_point_stamped
    from eye_in_hand.ros.qos import RESULT_QOS
    pub_first = feed.io.create_publisher(PointStamped, "target/point", RESULT_QOS)
    assert spin_until(executor, lambda: pub_first.get_subscription_count() > 0, 10.0)
    pts = {"a": np.array([0.02, -0.01, 0.45]), "b": np.array([-0.1, 0.05, 0.7])}
    # as detect_triangulate: the first target also on target/point, then every target
    pub_first.publish(xyz_to_point_stamped(pts["a"], stamp_ns=T0, frame_id=CAM))
    feed.frame(T0, pts)

    def edges():
        return {t.child_frame_id: t for m in tf_out for t in m.transforms}
    assert spin_until(executor, lambda: {"target_a", "target_b"} <= set(edges()), 10.0)
    for n in "ab":
        tr = edges()[f"target_{n}"]
        assert tr.header.frame_id == "base_link" and header_stamp_ns(tr) == T0
        want = base_T_cam[:3, :3] @ pts[n] + base_T_cam[:3, 3]
        np.testing.assert_allclose(transform_to_matrix(tr)[:3, 3], want, atol=1e-12)
    # one /tf name per target (not also target_0 for the first one)
    spin_until(executor, lambda: False, 0.3)
    assert set(edges()) == {"target_a", "target_b"}
    # the fixed camera hangs off the base frame on /tf_static
    assert spin_until(executor, lambda: any(t.child_frame_id == CAM for m in static_out
                                            for t in m.transforms), 10.0)
    he = [t for m in static_out for t in m.transforms if t.child_frame_id == CAM][0]
    assert he.header.frame_id == "base_link"
    np.testing.assert_allclose(transform_to_matrix(he), base_T_cam, atol=1e-9)


def test_detect_triangulate_refuses_ids_that_cannot_name_a_topic_and_keeps_a_bound(
        ros_context, executor, namespace, spin_until):
    from types import SimpleNamespace

    node = DetectTriangulateNode(context=ros_context, namespace=namespace, parameter_overrides=[
        Parameter("target_names", value=["red", "green"]), Parameter("max_targets", value=3),
        Parameter("targets.green.lower", value=[45, 120, 70]),
        Parameter("targets.green.upper", value=[75, 255, 255]),
        Parameter("targets.green.radius_m", value=0.0)])
    io = Node("io", context=ros_context, namespace=namespace)
    executor.add_node(node)
    executor.add_node(io)
    markers = _collect(io, MarkerArray, "targets/markers")
    red_1 = _collect(io, PointStamped, "targets/red_1/point")
    assert spin_until(executor, lambda: node.count_subscribers("targets/markers") > 0, 10.0)

    def loc(tid, name, x):
        return SimpleNamespace(id=tid, name=name, point_m=np.asarray(x, float),
                               covariance=np.eye(3) * 1e-8)
    # the configured names have publishers from the start: red_1 is the third and last id
    result = SimpleNamespace(targets=(
        loc("red", "red", [0.0, 0.0, 0.5]), loc("red_1", "red", [0.1, 0.0, 0.5]),
        loc("green", "green", [0.0, 0.1, 0.5]), loc("green_2", "green", [0.2, 0.1, 0.5]),
        loc("9x", "red", [0.0, 0.2, 0.5]), loc("a/b", "red", [0.0, 0.3, 0.5])))
    assert spin_until(executor, lambda: io.count_publishers("targets/red/point") > 0, 10.0)
    node.targets.publish_targets(result, T0, CAM)
    c = node.diag.snapshot().counters
    assert c["targets_located"] == 6 and c["target_points_published"] == 3
    assert c["targets_refused"] == 3 and c["marker_frames"] == 1
    assert {"bad_target_id", "too_many_targets"} <= set(node.diag.causes)
    assert spin_until(executor, lambda: len(markers) == 1 and len(red_1) == 1, 10.0)
    spheres = {m.ns: m for m in markers[0].markers[1:]}
    assert list(spheres) == ["red", "red_1", "green"]
    assert spheres["red_1"].color.r > 0.9 and spheres["red_1"].scale.x == pytest.approx(0.04)
    assert spheres["green"].scale.x == pytest.approx(0.04)      # unknown radius: the default
    assert (red_1[0].point.x, header_stamp_ns(red_1[0])) == (0.1, T0)


def test_the_node_takes_the_eye_to_hand_file_that_calibrate_handeye_writes(
        data_dir, tmp_path, ros_context, executor, namespace, spin_until):
    """Real data: 12 eye-to-hand pose pairs of the bundled MoveIt set through
    ``calibrate handeye --setup eye_to_hand``; the node reads that hand_eye.yaml as it is."""
    import json

    from eye_in_hand.cli import main
    from eye_in_hand.io.config import load_hand_eye

    pairs = tmp_path / "pairs.json"
    data = json.loads((data_dir / "moveit_eye_to_hand" / "pose_samples.json").read_text())
    pairs.write_text(json.dumps(data[:12]))
    out = tmp_path / "he"
    assert main(["calibrate", "handeye", "--pairs", str(pairs), "--setup", "eye_to_hand",
                 "-o", str(out), "--no-html"]) == 0
    calib = load_hand_eye(out / "hand_eye.yaml")
    assert calib.setup == "eye_to_hand" and calib.parent_frame == "base_link"
    feed = _Feed(ros_context, executor, namespace, {
        "hand_eye_file": str(out / "hand_eye.yaml"), "camera_frame": calib.child_frame})
    assert feed.node.eye_to_hand and feed.ready(executor, spin_until)
    p_cam = np.array([0.05, 0.02, 0.8])
    feed.pub_cov["a"].publish(pose_with_covariance(rclpy_types(), p_cam, np.eye(3) * 1e-8, T0,
                                                   calib.child_frame))
    feed.pub_markers.publish(sphere_marker_array([Sphere("a", p_cam, 0.04)], stamp_ns=T0,
                                                 frame_id=calib.child_frame))
    assert spin_until(executor, lambda: len(feed.covs["a"]) == 1, 10.0)
    p = feed.poses["a"][0].pose.position
    want, want_cov = target_in_base(np.eye(4), calib.transform, p_cam, cov_cam=np.eye(3) * 1e-8,
                                    cov_hand_eye=calib.covariance)
    assert np.allclose([p.x, p.y, p.z], want, atol=1e-12)
    got_cov = np.asarray(feed.covs["a"][0].pose.covariance).reshape(6, 6)[:3, :3]
    assert np.allclose(got_cov, want_cov, rtol=1e-9, atol=1e-18)
    assert calib.covariance is not None   # the hand-eye uncertainty is in the covariance
    assert np.trace(got_cov) > 3e-8 * 1.01


def test_per_target_topics_follow_the_remapped_marker_topic_as_the_launch_lays_them_out(
        tmp_path, ros_context, executor, namespace, spin_until):
    """``eye-in-hand launch``: detect_triangulate in <ns>/stereo with targets/markers remapped
    to <ns>; hand_eye in <ns>. The per-target topics (ids known only at run time) follow."""
    from types import SimpleNamespace

    detect = DetectTriangulateNode(
        context=ros_context, namespace=f"{namespace}/stereo",
        parameter_overrides=[Parameter("frame_id", value=CAM)],
        cli_args=["--ros-args", "-r", f"targets/markers:={namespace}/targets/markers"])
    feed = _Feed(ros_context, executor, namespace, {
        "hand_eye_file": str(_hand_eye_file(tmp_path, "eye_to_hand", np.eye(4), None))})
    executor.add_node(detect)
    red_1 = _collect(feed.io, PoseStamped, "target/red_1/pose")
    assert spin_until(executor, lambda: "red" in feed.node.targets.subs
                      and detect.targets.pub_markers.get_subscription_count() > 0, 15.0)
    assert detect.count_publishers(f"{namespace}/targets/red/point_cov") == 1

    def loc(tid, x):
        return SimpleNamespace(id=tid, name="red", point_m=np.asarray(x, float),
                               covariance=np.eye(3) * 1e-8)
    p = [0.1, 0.0, 0.5]
    detect.targets.publish_targets(SimpleNamespace(targets=(loc("red_1", p),)), T0, CAM)
    # red_1 is new: hand_eye subscribes when the frame lists it, under the remapped prefix,
    # and still gets that frame's point (transient local); the next frame comes through too
    assert spin_until(executor, lambda: feed.node.targets.subs.get("red_1") is not None and
                      detect.targets.per_target["red_1"][1].get_subscription_count() > 0
                      and len(red_1) == 1, 15.0)
    detect.targets.publish_targets(SimpleNamespace(targets=(loc("red_1", p),)), T0 + PERIOD_NS,
                                   CAM)
    assert spin_until(executor, lambda: len(red_1) == 2, 10.0)
    assert [header_stamp_ns(m) for m in red_1] == [T0, T0 + PERIOD_NS]
    assert red_1[1].pose.position.x == 0.1
    assert feed.node.diag.counter("target_refused.no_point") == 0


def test_first_frame_of_a_new_target_id_is_not_lost(tmp_path, ros_context, executor, namespace,
                                                     spin_until):
    """A blob-set id seen for the first time: detect_triangulate makes its publishers and sends
    its point before the frame's targets/markers tells hand_eye to subscribe; the point still
    arrives (transient local), every frame gives a pose, none twice, and points that no frame
    lists (sent before hand_eye existed) are dropped as orphans, never located."""
    from types import SimpleNamespace

    base_T_cam = from_rotvec([2.0, 0.3, -0.4], [0.8, -0.3, 1.1])
    detect = DetectTriangulateNode(context=ros_context, namespace=namespace, parameter_overrides=[
        Parameter("target_names", value=["red"])])
    io = Node("io", context=ros_context, namespace=namespace)
    executor.add_node(detect)
    executor.add_node(io)

    def frame(stamp, ids):
        detect.targets.publish_targets(SimpleNamespace(targets=tuple(
            SimpleNamespace(id=t, name="red", point_m=np.array([0.01 * k, 0.0, 0.5]),
                            covariance=np.eye(3) * 1e-8) for k, t in enumerate(ids))),
            stamp, CAM)

    frame(T0, ["red"])                      # before hand_eye exists: nobody lists it later
    hand_eye = HandEyeNode(context=ros_context, namespace=namespace, parameter_overrides=[
        Parameter("hand_eye_file", value=str(_hand_eye_file(tmp_path, "eye_to_hand",
                                                            base_T_cam, None))),
        Parameter("max_target_wait_s", value=5.0), Parameter("discovery_period_s", value=600.0)])
    executor.add_node(hand_eye)
    poses = {t: _collect(io, PoseStamped, f"target/{t}/pose") for t in ("red", "red_1")}
    arrays = _collect(io, PoseArray, "target/poses")
    assert spin_until(executor, lambda: "red" in hand_eye.targets.subs
                      and detect.targets.pub_markers.get_subscription_count() > 0
                      and io.count_publishers("target/poses") > 0
                      and io.count_publishers("target/red/pose") > 0, 15.0)
    assert "red_1" not in hand_eye.targets.subs and "red_1" not in detect.targets.per_target
    stamps = [T0 + k * PERIOD_NS for k in (1, 2, 3)]
    frame(stamps[0], ["red", "red_1"])     # red_1 appears: publisher made, point sent at once
    assert spin_until(executor, lambda: len(arrays) == 1, 15.0), (
        hand_eye.diag.snapshot().counters, hand_eye.diag.causes)
    assert spin_until(executor, lambda: io.count_publishers("target/red_1/pose") > 0, 10.0)
    for s in stamps[1:]:
        frame(s, ["red", "red_1"])
        assert spin_until(executor, lambda s=s: len(arrays) == stamps.index(s) + 1, 15.0)
    assert spin_until(executor, lambda: all(len(poses[t]) == 3 for t in poses), 10.0), (
        {t: len(p) for t, p in poses.items()}, hand_eye.diag.snapshot().counters)
    spin_until(executor, lambda: False, 0.2)    # anything extra would arrive now
    assert [len(a.poses) for a in arrays] == [2, 2, 2]
    for t in poses:
        assert [header_stamp_ns(p) for p in poses[t]] == stamps    # once each, in order
    c = hand_eye.diag.snapshot().counters
    assert c["target_refused.no_point"] == 0 and c["targets_rejected"] == 0
    assert c["target_poses_published"] == 6
    assert c["target_points_received"] == 7 and c["orphan_target_points"] == 1
