"""In-process tests of the stereo_capture node: paired, same-stamp images from the images and
sim sources, start-up failures naming the source, unreadable frames counted on diagnostics."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import qos_profile_sensor_data  # noqa: E402

from eye_in_hand.errors import ConfigError  # noqa: E402


def _write_pairs(folder: Path, n: int, *, corrupt: int | None = None) -> None:
    rng = np.random.default_rng(3)
    (folder / "left").mkdir(parents=True)
    (folder / "right").mkdir(parents=True)
    for i in range(n):
        for side, val in (("left", 10 * i), ("right", 10 * i + 5)):
            img = np.full((48, 64, 3), val, np.uint8)
            img[0, 0] = rng.integers(0, 255, 3)
            path = folder / side / f"{i:03d}.png"
            if corrupt == i and side == "right":
                path.write_bytes(b"not a png")
            else:
                cv2.imwrite(str(path), img)


class _Collector:
    def __init__(self, node, ns: str) -> None:
        from sensor_msgs.msg import CameraInfo, Image

        self.msgs: dict[str, list] = {k: [] for k in ("left", "right", "linfo", "rinfo")}
        for key, typ, topic in (("left", Image, "left/image_raw"),
                                ("right", Image, "right/image_raw"),
                                ("linfo", CameraInfo, "left/camera_info"),
                                ("rinfo", CameraInfo, "right/camera_info")):
            node.create_subscription(typ, f"{ns}/{topic}",
                                     lambda m, k=key: self.msgs[k].append(m),
                                     qos_profile_sensor_data)

    def stamps(self, key: str) -> list[int]:
        return [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in self.msgs[key]]


def _params(**kw) -> list[Parameter]:
    return [Parameter(k.replace("__", "."), value=v) for k, v in kw.items()]


def test_images_source_publishes_paired_same_stamp_frames(tmp_path, ros_context, executor,
                                                          namespace, spin_until):
    from eye_in_hand.nodes.stereo_capture import StereoCaptureNode

    _write_pairs(tmp_path, 4)
    node = StereoCaptureNode(context=ros_context, namespace=namespace,
                             parameter_overrides=_params(
                                 source="images", rate_hz=50.0,
                                 images__left=str(tmp_path / "left"),
                                 images__right=str(tmp_path / "right" / "*.png"),
                                 images__loop=False))
    listener = rclpy.create_node("listener", context=ros_context)
    col = _Collector(listener, namespace)
    executor.add_node(node)
    executor.add_node(listener)
    assert spin_until(executor, lambda: len(col.msgs["right"]) >= 4
                      and len(col.msgs["rinfo"]) >= 4, 15.0)
    left, right = col.msgs["left"], col.msgs["right"]
    assert col.stamps("left") == col.stamps("right") == col.stamps("linfo")
    assert len(set(col.stamps("left"))) == 4
    for i, (lm, rm) in enumerate(zip(left, right, strict=True)):
        assert lm.encoding == "bgr8" and (lm.width, lm.height) == (64, 48)
        assert lm.header.frame_id == "camera_left_optical_frame"
        assert rm.header.frame_id == "camera_right_optical_frame"
        assert lm.data[3] == 10 * i and rm.data[3] == 10 * i + 5   # sorted order, paired
    assert col.msgs["linfo"][0].width == 64   # uncalibrated: size only


def test_unreadable_frame_is_counted_and_node_keeps_going(tmp_path, ros_context, executor,
                                                          namespace, spin_until):
    from diagnostic_msgs.msg import DiagnosticArray

    from eye_in_hand.nodes.stereo_capture import StereoCaptureNode

    _write_pairs(tmp_path, 3, corrupt=1)
    node = StereoCaptureNode(context=ros_context, namespace=namespace,
                             parameter_overrides=_params(
                                 source="images", rate_hz=50.0, diagnostics_period_s=0.1,
                                 images__left=str(tmp_path / "left"),
                                 images__right=str(tmp_path / "right")))
    listener = rclpy.create_node("listener", context=ros_context)
    col = _Collector(listener, namespace)
    diags: list = []
    listener.create_subscription(DiagnosticArray, f"{namespace}/diagnostics", diags.append, 10)
    executor.add_node(node)
    executor.add_node(listener)

    def failure_seen() -> bool:
        return any(kv.key.startswith("read_failures") and kv.value not in ("0", "0.0")
                   for d in diags for s in d.status for kv in s.values)

    assert spin_until(executor, lambda: len(col.msgs["left"]) >= 2 and failure_seen(), 15.0)
    assert [m.data[3] for m in col.msgs["left"]] == [0, 20]   # pair 1 skipped, pair 2 sent
    assert node.diag.counter("read_failures") == 1


def test_missing_source_fails_at_startup_naming_it(tmp_path, ros_context, namespace):
    from eye_in_hand.nodes.stereo_capture import StereoCaptureNode

    with pytest.raises(ConfigError, match="images.left"):
        StereoCaptureNode(context=ros_context, namespace=namespace,
                          parameter_overrides=_params(source="images",
                                                      images__left=str(tmp_path / "none"),
                                                      images__right=str(tmp_path)))
    with pytest.raises(ConfigError, match="video.left.*nothing.avi"):
        StereoCaptureNode(context=ros_context, namespace=namespace,
                          parameter_overrides=_params(source="video",
                                                      video__left=str(tmp_path / "nothing.avi"),
                                                      side_by_side=True))


def test_sim_source_publishes_paired_frames_with_robot_state(ros_context, executor, namespace,
                                                             spin_until):
    from geometry_msgs.msg import PoseStamped

    from eye_in_hand.nodes.stereo_capture import StereoCaptureNode
    from eye_in_hand.ros.geometry import pose_to_matrix
    from eye_in_hand.sim import World

    node = StereoCaptureNode(context=ros_context, namespace=namespace,
                             parameter_overrides=_params(
                                 source="sim", rate_hz=20.0, sim__width=160, sim__height=90,
                                 sim__duration_s=1.0))
    listener = rclpy.create_node("listener", context=ros_context)
    col = _Collector(listener, namespace)
    poses: list = []
    listener.create_subscription(PoseStamped, f"{namespace}/ee_pose", poses.append, 10)
    executor.add_node(node)
    executor.add_node(listener)
    assert spin_until(executor, lambda: len(col.msgs["right"]) >= 3 and len(poses) >= 3
                      and len(col.msgs["rinfo"]) >= 3, 30.0)
    n = min(len(col.msgs["left"]), len(col.msgs["right"]))
    assert col.stamps("left")[:n] == col.stamps("right")[:n]
    lm = col.msgs["left"][0]
    assert (lm.width, lm.height, lm.encoding) == (160, 90, "bgr8")
    info = col.msgs["rinfo"][0]
    assert info.p[3] < 0  # right projection carries -fx * baseline
    world = World.default()
    stamp_of = {p.header.stamp.sec * 10**9 + p.header.stamp.nanosec: p for p in poses}
    common = set(stamp_of) & set(col.stamps("left"))
    assert common, "ee_pose is stamped with the image stamps"
    T = pose_to_matrix(stamp_of[min(common)].pose)
    dist = np.linalg.norm(T[:3, 3] - world.targets[0].center_base)
    assert 0.2 < dist < 0.8   # the trajectory circles the target


def test_video_source_splits_side_by_side_frames(tmp_path, ros_context, executor, namespace,
                                                 spin_until):
    from eye_in_hand.nodes.stereo_capture import StereoCaptureNode

    path = tmp_path / "sbs.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (128, 48))
    if not writer.isOpened():
        pytest.skip("this OpenCV build cannot write MJPG video")
    for i in range(4):
        img = np.zeros((48, 128, 3), np.uint8)
        img[:, :64] = 40 * i
        img[:, 64:] = 200 - 20 * i
        writer.write(img)
    writer.release()
    node = StereoCaptureNode(context=ros_context, namespace=namespace,
                             parameter_overrides=_params(source="video", rate_hz=50.0,
                                                         video__left=str(path),
                                                         side_by_side=True))
    listener = rclpy.create_node("listener", context=ros_context)
    col = _Collector(listener, namespace)
    executor.add_node(node)
    executor.add_node(listener)
    assert spin_until(executor, lambda: len(col.msgs["right"]) >= 4, 15.0)
    assert col.stamps("left")[:4] == col.stamps("right")[:4]
    for i, (lm, rm) in enumerate(zip(col.msgs["left"][:4], col.msgs["right"][:4], strict=True)):
        assert (lm.width, lm.height) == (64, 48) == (rm.width, rm.height)
        assert abs(int(lm.data[0]) - 40 * i) <= 3 and abs(int(rm.data[0]) - (200 - 20 * i)) <= 3


def test_sim_source_follows_joint_states(ros_context, executor, namespace, spin_until):
    from sensor_msgs.msg import JointState

    from eye_in_hand.nodes.stereo_capture import StereoCaptureNode
    from eye_in_hand.sim import World
    from eye_in_hand.sim.scenarios import localization_trajectory

    node = StereoCaptureNode(context=ros_context, namespace=namespace,
                             parameter_overrides=_params(
                                 source="sim", rate_hz=20.0, sim__width=160, sim__height=90,
                                 sim__follow_joint_states=True, sim__noise_sigma=0.0))
    listener = rclpy.create_node("listener", context=ros_context)
    col = _Collector(listener, namespace)
    pub = listener.create_publisher(JointState, f"{namespace}/joint_states", 10)
    executor.add_node(node)
    executor.add_node(listener)
    assert not spin_until(executor, lambda: len(col.msgs["left"]) > 0, 0.5)  # nothing yet
    world = World.default().with_image_size(160, 90)
    q = localization_trajectory(world, 0.1, 10.0, seed=0)[0][1]
    js = JointState()
    js.name = list(reversed(world.arm.joint_names))         # any order, matched by name
    js.position = [float(v) for v in reversed(q)]
    listener.create_timer(0.05, lambda: pub.publish(js))   # a robot driver at 20 Hz
    assert spin_until(executor, lambda: len(col.msgs["left"]) >= 2, 20.0)
    expected = world.render(q, noise_sigma=0.0, supersample=2)
    got = np.frombuffer(bytes(col.msgs["left"][-1].data), np.uint8).reshape(90, 160, 3)
    np.testing.assert_array_equal(got, expected.left)


def test_followed_pair_carries_the_stamp_of_the_joint_state_it_shows(ros_context, executor,
                                                                     namespace, spin_until):
    """A camera stamps a frame with its exposure: a pair rendered from a joint state has that
    state's stamp (not the publication time, which is a render later), and one state gives at
    most one pair."""
    from sensor_msgs.msg import JointState

    from eye_in_hand.nodes.stereo_capture import StereoCaptureNode
    from eye_in_hand.ros.stamps import header_stamp_ns, make_header
    from eye_in_hand.sim import World
    from eye_in_hand.sim.scenarios import localization_trajectory

    node = StereoCaptureNode(context=ros_context, namespace=namespace,
                             parameter_overrides=_params(
                                 source="sim", rate_hz=30.0, sim__width=160, sim__height=90,
                                 sim__follow_joint_states=True, sim__noise_sigma=0.0))
    listener = rclpy.create_node("listener", context=ros_context)
    col = _Collector(listener, namespace)
    pub = listener.create_publisher(JointState, f"{namespace}/joint_states", 10)
    executor.add_node(node)
    executor.add_node(listener)
    world = World.default().with_image_size(160, 90)
    traj = localization_trajectory(world, 1.0, 10.0, seed=0)
    sent: list[int] = []

    def send() -> None:
        k = len(sent)
        if k >= len(traj):
            return
        stamp = 1_700_000_000_000_000_000 + 100_000_000 * k   # stamps far from the clock
        js = JointState(header=make_header(stamp, ""), name=list(world.arm.joint_names),
                        position=[float(v) for v in traj[k][1]])
        pub.publish(js)
        sent.append(stamp)

    listener.create_timer(0.15, send)          # slower than the camera: repeats would show
    assert spin_until(executor, lambda: len(sent) == len(traj) and len(col.msgs["left"]) >= 4,
                      30.0)
    spin_until(executor, lambda: False, 0.5)
    stamps = [header_stamp_ns(m) for m in col.msgs["left"]]
    assert set(stamps) <= set(sent)            # every pair shows a state, stamped with it
    assert len(stamps) == len(set(stamps))     # and no state twice
    k = sent.index(stamps[-1])
    expected = world.render(traj[k][1], noise_sigma=0.0, supersample=2)
    got = np.frombuffer(bytes(col.msgs["left"][-1].data), np.uint8).reshape(90, 160, 3)
    np.testing.assert_array_equal(got, expected.left)
