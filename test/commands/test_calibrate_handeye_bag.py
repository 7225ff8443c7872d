"""``calibrate handeye --bag``: still-robot sampling, pose interpolation at the image stamp."""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from eye_in_hand.cli import main
from eye_in_hand.core.camera import CameraModel
from eye_in_hand.core.handeye.synthetic import make_problem
from eye_in_hand.core.transforms import (
    from_rotvec,
    interpolate,
    invert,
    to_xyz_quat,
    transform_distance,
)
from eye_in_hand.errors import ConfigError
from eye_in_hand.io.bag_samples import read_bag_samples
from eye_in_hand.io.bags import BagWriter, default_typestore
from eye_in_hand.io.config import load_hand_eye

T0 = 1_700_000_000_000_000_000
HOLD_NS, MOVE_NS = 300_000_000, 300_000_000
IMAGE_PERIOD_NS, ROBOT_PERIOD_NS, ROBOT_OFFSET_NS = 50_000_000, 10_000_000, 3_000_000


def _render(cam: CameraModel, T: np.ndarray, cols: int = 9, rows: int = 6, sq: float = 0.025,
            scale: int = 4) -> np.ndarray:
    """Fast anti-aliased chessboard (filled distorted squares at 4x, area downsampling)."""
    img = np.full((cam.height * scale, cam.width * scale), 110, np.uint8)
    t = np.linspace(0.0, 1.0, 9)

    def poly(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
        pts = np.concatenate([np.stack([x0 + (x1 - x0) * t, np.full(9, y0)], 1),
                              np.stack([np.full(9, x1), y0 + (y1 - y0) * t], 1),
                              np.stack([x1 - (x1 - x0) * t, np.full(9, y1)], 1),
                              np.stack([np.full(9, x0), y1 - (y1 - y0) * t], 1)])
        P = np.hstack([pts, np.zeros((len(pts), 1))]) @ T[:3, :3].T + T[:3, 3]
        return np.round((cam.project(P) * scale + (scale - 1) / 2.0) * 16).astype(np.int32)

    cv2.fillPoly(img, [poly(-2 * sq, -2 * sq, (cols + 1) * sq, (rows + 1) * sq)], 230,
                 cv2.LINE_8, 4)
    for i in range(-1, cols):
        for j in range(-1, rows):
            if (i + j) % 2 == 0:
                cv2.fillPoly(img, [poly(i * sq, j * sq, (i + 1) * sq, (j + 1) * sq)], 25,
                             cv2.LINE_8, 4)
    return cv2.resize(img, (cam.width, cam.height), interpolation=cv2.INTER_AREA)


class _Msgs:
    def __init__(self) -> None:
        self.t = default_typestore().types

    def header(self, ns: int, frame: str):
        stamp = self.t["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
        return self.t["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def image(self, img: np.ndarray, ns: int):
        h, w = img.shape
        return self.t["sensor_msgs/msg/Image"](
            header=self.header(ns, "camera_optical_frame"), height=h, width=w,
            encoding="mono8", is_bigendian=0, step=w, data=img.reshape(-1).copy())

    def camera_info(self, cam: CameraModel, ns: int):
        roi = self.t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0,
                                                         width=0, do_rectify=False)
        return self.t["sensor_msgs/msg/CameraInfo"](
            header=self.header(ns, "camera_optical_frame"), height=cam.height,
            width=cam.width, distortion_model="plumb_bob", d=cam.dist.copy(),
            k=cam.K.reshape(9).copy(), r=np.eye(3).reshape(9), p=cam.P.reshape(12).copy(),
            binning_x=0, binning_y=0, roi=roi)

    def tf(self, edges: list[tuple[str, str, np.ndarray]], ns: int):
        out = []
        for parent, child, T in edges:
            xyz, q = to_xyz_quat(T)
            tr = self.t["geometry_msgs/msg/Transform"](
                translation=self.t["geometry_msgs/msg/Vector3"](x=xyz[0], y=xyz[1], z=xyz[2]),
                rotation=self.t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2],
                                                               w=q[3]))
            out.append(self.t["geometry_msgs/msg/TransformStamped"](
                header=self.header(ns, parent), child_frame_id=child, transform=tr))
        return self.t["tf2_msgs/msg/TFMessage"](transforms=out)

    def pose_stamped(self, T: np.ndarray, ns: int):
        xyz, q = to_xyz_quat(T)
        pose = self.t["geometry_msgs/msg/Pose"](
            position=self.t["geometry_msgs/msg/Point"](x=xyz[0], y=xyz[1], z=xyz[2]),
            orientation=self.t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]))
        return self.t["geometry_msgs/msg/PoseStamped"](header=self.header(ns, "base_link"),
                                                       pose=pose)


@pytest.fixture(scope="module")
def calib_bag(tmp_path_factory):
    """Mono camera on the flange, 7 stops (the 4th with the board hidden), moves between."""
    cam = CameraModel(K=np.array([[560.0, 0, 320], [0, 560.0, 200], [0, 0, 1]]),
                      dist=np.array([-0.1, 0.05, 0, 0, 0]), width=640, height=400,
                      name="camera")
    P = make_problem(7, seed=9, noise_px=0.0, camera=cam)
    stops = list(P.true_base_T_ee)
    hidden = 3
    # Timeline: stop k held on [k*(H+M), k*(H+M)+H], then a move to stop k+1.
    period = HOLD_NS + MOVE_NS
    end = len(stops) * period - MOVE_NS

    def robot_at(t: int) -> np.ndarray:
        k = min(t // period, len(stops) - 1)
        s = t - k * period
        if s <= HOLD_NS or k == len(stops) - 1:
            return stops[k]
        return interpolate(s - HOLD_NS, 0, stops[k], MOVE_NS, stops[k + 1])

    m = _Msgs()
    path = tmp_path_factory.mktemp("bag") / "calib"
    w = BagWriter(path)
    w.add_topic("/cam/image_raw", "sensor_msgs/msg/Image")
    w.add_topic("/cam/camera_info", "sensor_msgs/msg/CameraInfo")
    w.add_topic("/ee_pose", "geometry_msgs/msg/PoseStamped")
    w.add_topic("/tf", "tf2_msgs/msg/TFMessage")
    w.add_topic("/tf_static", "tf2_msgs/msg/TFMessage")
    events = []
    # /tf: base_link -> shoulder (moving) -> tool0, and a static camera frame off tool0.
    events.append((T0, "/tf_static", m.tf([("tool0", "camera", P.X)], T0)))
    for t in range(0, end + 1, ROBOT_PERIOD_NS):
        rt = t + ROBOT_OFFSET_NS
        T = robot_at(rt)
        events.append((T0 + rt, "/ee_pose", m.pose_stamped(T, T0 + rt)))
        shoulder = from_rotvec([0.0, 0.0, 1e-9 * rt], [0.0, 0.0, 0.1])
        events.append((T0 + rt, "/tf", m.tf([("base_link", "shoulder", shoulder),
                                             ("shoulder", "tool0", invert(shoulder) @ T)],
                                            T0 + rt)))
    for t in range(IMAGE_PERIOD_NS, end, IMAGE_PERIOD_NS):
        k = min(t // period, len(stops) - 1)
        hold = t - k * period <= HOLD_NS
        if hold and k == hidden:
            img = np.full((400, 640), 110, np.uint8)
        else:
            cam_T_board = invert(robot_at(t) @ P.X) @ P.Y
            img = _render(cam, cam_T_board)
        events.append((T0 + t, "/cam/image_raw", m.image(img, T0 + t)))
        events.append((T0 + t, "/cam/camera_info", m.camera_info(cam, T0 + t)))
    for stamp, topic, msg in sorted(events, key=lambda e: e[0]):
        w.write(topic, stamp, msg)
    w.close()
    return path, P.X, len(stops)


def test_read_bag_samples_finds_still_stops(calib_bag) -> None:
    path, _, n_stops = calib_bag
    found = read_bag_samples(path)
    assert found.image_topics == {"image": "/cam/image_raw"}
    assert found.pose_source.startswith("/ee_pose")
    assert len(found.samples) == n_stops
    assert found.camera is not None and found.rig is None
    moving = [s for s in found.skipped if s["reason"] == "robot moving"]
    assert len(moving) >= n_stops  # images during the moves are never used
    for s in found.samples:
        assert s.images["image"].shape == (400, 640)
        # Every chosen image is taken while the robot holds a stop.
        assert (s.stamp_ns - T0) % (HOLD_NS + MOVE_NS) <= HOLD_NS


def test_tf_pose_source_matches_pose_topic(calib_bag) -> None:
    path, _, n_stops = calib_bag
    a = read_bag_samples(path, pose_topic="/ee_pose")
    b = read_bag_samples(path, use_tf=True)
    assert b.pose_source == "/tf base_link -> tool0"
    assert [s.stamp_ns for s in a.samples] == [s.stamp_ns for s in b.samples]
    assert len(b.samples) == n_stops
    for sa, sb in zip(a.samples, b.samples, strict=True):
        np.testing.assert_allclose(sa.base_T_ee, sb.base_T_ee, atol=1e-9)
    with pytest.raises(ConfigError, match="no chain from 'base_link' to 'flange'"):
        read_bag_samples(path, use_tf=True, ee_frame="flange")


def test_bag_end_to_end(calib_bag, tmp_path: Path, capsys) -> None:
    path, X, n_stops = calib_bag
    out = tmp_path / "out"
    rc = main(["calibrate", "handeye", "--bag", str(path), "--board", "chessboard:9x6:0.025",
               "--left-topic", "image_raw", "--no-html", "-o", str(out)])
    assert rc == 0
    err = capsys.readouterr().err
    assert "board not found" in err and "stop003" in err
    report = json.loads((out / "report.json").read_text())
    assert report["input"]["type"] == "bag" and report["input"]["count"] == n_stops
    assert [s["name"] for s in report["skipped"]] == ["stop003"]
    calib = load_hand_eye(out / "hand_eye.yaml")
    assert calib.sample_count == n_stops - 1
    dt, dr = transform_distance(X, calib.transform)
    assert dt < 0.001 and np.degrees(dr) < 0.1, (dt, np.degrees(dr))


def test_robot_pose_tf_gives_the_pose_topic_result(calib_bag, tmp_path: Path, capsys) -> None:
    """--robot-pose tf (--base-frame -> --ee-frame) and the deprecated --tf: the X of /ee_pose."""
    path, _, _ = calib_bag
    common = ["calibrate", "handeye", "--bag", str(path), "--board", "chessboard:9x6:0.025",
              "--no-html"]
    X = {}
    for name, extra in (("ee_pose", ["--robot-pose", "ee_pose"]), ("tf", ["--robot-pose", "tf"]),
                        ("old_tf", ["--tf"])):
        assert main(common + extra + ["-o", str(tmp_path / name)]) == 0
        report = json.loads((tmp_path / name / "report.json").read_text())
        assert report["input"]["pose_source"].startswith("/tf" if "tf" in name else "/ee_pose")
        X[name] = load_hand_eye(tmp_path / name / "hand_eye.yaml").transform
    assert "--tf is deprecated" in capsys.readouterr().err
    for name in ("tf", "old_tf"):
        dt, dr = transform_distance(X["ee_pose"], X[name])
        assert dt < 1e-6 and dr < 1e-6, (name, dt, dr)


def test_bag_errors(calib_bag, tmp_path: Path, capsys) -> None:
    path, _, _ = calib_bag
    assert main(["calibrate", "handeye", "--bag", str(path), "-o", str(tmp_path)]) == 1
    assert "--bag needs --board" in capsys.readouterr().err
    assert main(["calibrate", "handeye", "--bag", str(path), "--board", "chessboard:9x6:0.025",
                 "--robot-pose", "ee_pose", "--ee-pose-topic", "/nope", "-o", str(tmp_path)]) == 1
    assert "no pose topic '/nope'" in capsys.readouterr().err
    assert main(["calibrate", "handeye", "--bag", str(path), "--board", "chessboard:9x6:0.025",
                 "--robot-pose", "joint_states", "-o", str(tmp_path)]) == 1
    assert "--kinematics" in capsys.readouterr().err


def test_a_board_given_in_squares_is_named_with_the_fix(calib_bag, tmp_path: Path,
                                                        capsys) -> None:
    """The trap: `10x7` (squares) for a 9x6 board: a "skipped" line per stop, then a failure
    with no hint. With fewer stops than the early check waits for, it runs at the end."""
    path, _, n_stops = calib_bag
    out = tmp_path / "out"
    assert main(["calibrate", "handeye", "--bag", str(path), "--board", "chessboard:10x7:0.025",
                 "--image-topic", "image_raw", "--no-html", "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert (f"no board chessboard:10x7:0.025 found in the first {n_stops} still stops' "
            f"images; a 9x6 chessboard (inner corners) is found in {n_stops - 1} of them") in err
    assert "Pass --board chessboard:9x6:0.025" in err and not out.exists()


def _legs_bag(path: Path, legs) -> None:
    """A bag of robot poses at 100 Hz along ``legs`` ``(t0, t1, P0, P1)`` (linear from P0 to
    P1; P0 alone when they are the same object) and tiny blank images at 20 Hz."""
    cam = CameraModel(K=np.array([[50.0, 0, 32], [0, 50.0, 20], [0, 0, 1]]),
                      dist=np.zeros(5), width=64, height=40, name="camera")
    end = legs[-1][1]

    def robot_at(t: int) -> np.ndarray:
        for t0, t1, P0, P1 in legs:
            if t <= t1:
                return P0 if P0 is P1 else interpolate(t - t0, 0, P0, t1 - t0, P1)
        return legs[-1][3]

    m = _Msgs()
    w = BagWriter(path)
    for topic, kind in (("/cam/image_raw", "sensor_msgs/msg/Image"),
                        ("/cam/camera_info", "sensor_msgs/msg/CameraInfo"),
                        ("/ee_pose", "geometry_msgs/msg/PoseStamped")):
        w.add_topic(topic, kind)
    events = [(T0 + t, "/ee_pose", m.pose_stamped(robot_at(t), T0 + t))
              for t in range(0, end + 1, ROBOT_PERIOD_NS)]
    for t in range(IMAGE_PERIOD_NS, end, IMAGE_PERIOD_NS):
        events.append((T0 + t, "/cam/image_raw", m.image(np.full((40, 64), 90, np.uint8),
                                                         T0 + t)))
        events.append((T0 + t, "/cam/camera_info", m.camera_info(cam, T0 + t)))
    for stamp, topic, msg in sorted(events, key=lambda e: e[0]):
        w.write(topic, stamp, msg)
    w.close()


@pytest.fixture(scope="module")
def stops_bag(tmp_path_factory):
    """Two stops of 1 s joined by a 0.5 s turn in place (20 deg about z, no translation),
    a 0.5 s straight move, and a third stop."""
    A = from_rotvec([np.pi, 0.0, 0.0], [0.4, 0.0, 0.3])
    B = A @ from_rotvec([0.0, 0.0, np.radians(20.0)], [0.0, 0.0, 0.0])
    C = from_rotvec([0.0, 0.0, 0.1], [0.0, 0.0, 0.0]) @ B
    C[:3, 3] = B[:3, 3] + [0.1, 0.0, 0.0]
    S = 1_000_000_000
    path = tmp_path_factory.mktemp("stops") / "stops"
    _legs_bag(path, [(0, S, A, A), (S, S + S // 2, A, B), (S + S // 2, 5 * S // 2, B, B),
                     (5 * S // 2, 3 * S, B, C), (3 * S, 4 * S, C, C)])
    return path, S


def test_a_slow_drift_is_not_one_stop(tmp_path: Path) -> None:
    """Still at every image (2 mm/s: 0.2 mm within the window), but a stop is the poses
    within the stillness limits of its first one: 4 mm of drift are several stops."""
    A = from_rotvec([np.pi, 0.0, 0.0], [0.4, 0.0, 0.3])
    B = A.copy()
    B[:3, 3] += [0.004, 0.0, 0.0]
    S = 1_000_000_000
    _legs_bag(tmp_path / "drift", [(0, 2 * S, A, B)])
    found = read_bag_samples(tmp_path / "drift")
    assert not [d for d in found.skipped if d["reason"] == "robot moving"]
    assert len(found.samples) >= 4


def test_bag_stops_rotation_window_and_middle_image(stops_bag) -> None:
    """A turn in place is motion (still = within both the translation and the rotation
    limit); the stillness window is ``still_window_s`` wide, centred on the image stamp; a stop
    is represented by its middle still image."""
    path, S = stops_bag
    found = read_bag_samples(path, still_window_s=0.2)
    stamps = [s.stamp_ns - T0 for s in found.samples]
    assert len(stamps) == 3, stamps
    moving = {d["stamp_ns"] - T0 for d in found.skipped if d["reason"] == "robot moving"}
    # 100 ms half window: 0.9 s is still (poses up to 1.0 s), 0.95 s sees the turn
    assert S - S // 20 in moving and S - S // 10 not in moving
    assert all(S + k * S // 20 in moving for k in range(1, 10))     # during the turn
    # the first stop's still images run 0.05-0.9 s: the middle one of 18 is the 10th, 0.5 s
    assert stamps[0] == S // 2
    assert abs(stamps[1] - 2 * S) <= S // 20
