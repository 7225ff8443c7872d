"""A robot bag as a real cell records it (/tf, /tf_static, /joint_states, images, camera_info;
no /ee_pose) through every path: ``process --robot-pose tf``, ``calibrate handeye --bag`` and
live replay (``play`` + detect_triangulate + hand_eye with ``robot_pose_source: tf``)."""
from __future__ import annotations

import csv
import json
import subprocess
import sys

import numpy as np
import pytest
import yaml

from eye_in_hand.cli import main
from eye_in_hand.core.transforms import transform_distance
from eye_in_hand.io.bags import bag_info
from eye_in_hand.io.config import HandEyeCalibration, load_hand_eye, save_hand_eye
from eye_in_hand.sim import World
from eye_in_hand.sim.output import RenderOptions, write_bag


@pytest.fixture(scope="module")
def tf_bag(tmp_path_factory):
    """A 10-pair localization bag at 480x270 with the robot only on /tf + /joint_states."""
    out = tmp_path_factory.mktemp("tfbag") / "loc"
    world = World.default().with_image_size(480, 270)
    write_bag(world, out, scenario="localization", frames=10, seed=4, ee_pose=False,
              render=RenderOptions(supersample=1))
    return out, world


def _hand_eye(tmp_path, world, correction=None):
    path = tmp_path / "hand_eye.yaml"
    save_hand_eye(path, HandEyeCalibration(
        setup="eye_in_hand", parent_frame="tool0", child_frame="camera_left_optical_frame",
        transform=world.ee_T_cam, method="ground_truth", robot_pose_correction=correction))
    return path


def _correction():
    """A robot pose correction of a few mm over the bag's orientations (systematic model)."""
    from eye_in_hand.core.pose_correction import RobotPoseCorrection
    from eye_in_hand.core.transforms import from_rotvec

    return RobotPoseCorrection(
        np.array([[0.02, -0.015, 0.0], [0.015, -0.01, -0.008], [-0.005, 0.002, 0.002]]),
        np.array([[0.004, 0.002, 0.0], [-0.003, 0.001, 0.002], [0.0, 0.003, -0.002]]),
        from_rotvec(np.array([np.pi, 0.0, 0.0]))[:3, :3])


def _base_points(out):
    rows = list(csv.DictReader((out / "results.csv").open()))
    return {int(r["stamp_ns"]): np.array([float(r[k]) for k in ("x_base", "y_base", "z_base")])
            for r in rows if r["status"] == "ok"}


def test_the_bag_has_the_shape_of_a_real_cell(tf_bag):
    topics = bag_info(tf_bag[0]).topics
    assert "/ee_pose" not in topics
    assert {"/tf", "/tf_static", "/joint_states", "/stereo/left/image_raw",
            "/stereo/left/camera_info"} <= set(topics)


def test_process_with_tf_equals_joint_states_kinematics(tf_bag, tmp_path, capsys):
    bag, world = tf_bag
    he = str(_hand_eye(tmp_path, world))
    # the default source (ee_pose) is not in this bag: one clear line
    assert main(["process", str(bag), "--hand-eye", he, "-o", str(tmp_path / "x"),
                 "--quiet"]) == 1
    assert "/ee_pose" in capsys.readouterr().err
    a, b = tmp_path / "tf", tmp_path / "js"
    assert main(["process", str(bag), "--hand-eye", he, "-o", str(a), "--quiet",
                 "--robot-pose", "tf"]) == 0
    text = capsys.readouterr().out
    assert "RMS" in text
    kin = tmp_path / "arm.yaml"
    kin.write_text(yaml.safe_dump({"arm": world.arm.to_dict()}))
    assert main(["process", str(bag), "--hand-eye", he, "-o", str(b), "--quiet",
                 "--robot-pose", "joint_states", "--kinematics", str(kin)]) == 0
    summary = json.loads((a / "summary.json").read_text())
    assert summary["counts"]["localized"] == 10 and summary["counts"]["bad_messages"] == 0
    assert summary["error"]["rms_mm"] < 4.0
    pa, pb = _base_points(a), _base_points(b)
    assert sorted(pa) == sorted(pb) and len(pa) == 10
    # TF interpolates every joint's transform, then chains; joint_states interpolates the
    # chained tool pose: the two differ at second order in the 8 ms robot period (about 1 um
    # here), while a pose taken at the wrong stamp (a sample 4 ms away) is off by mm
    assert max(np.linalg.norm(pa[s] - pb[s]) for s in pa) < 1e-5
    # frames that the TF chain does not reach are refused, not guessed
    c = tmp_path / "c"
    capsys.readouterr()
    assert main(["process", str(bag), "--hand-eye", he, "-o", str(c), "--quiet",
                 "--robot-pose", "tf", "--ee-frame", "flange"]) == 3   # nothing located
    assert "nothing located in the base frame" in capsys.readouterr().err
    counts = json.loads((c / "summary.json").read_text())["counts"]
    assert counts["localized"] == 0 and counts["no_robot_pose"] == 10


def test_calibrate_handeye_from_a_tf_only_bag(tmp_path, capsys):
    world = World.default().with_image_size(480, 270)
    bag = tmp_path / "cal"
    write_bag(world, bag, scenario="calibration", frames=5, seed=1, still_images_only=True,
              hold_frames=1, ee_pose=False, render=RenderOptions(supersample=1))
    out = tmp_path / "out"
    rc = main(["calibrate", "handeye", "--bag", str(bag), "--board", "chessboard:9x6:0.025",
               "--left-topic", "/stereo/left/image_raw", "--no-html", "-o", str(out)])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    report = json.loads((out / "report.json").read_text())
    assert "/tf" in json.dumps(report["input"])
    X = load_hand_eye(out / "hand_eye.yaml").transform
    dt, dr = transform_distance(world.ee_T_cam, X)
    assert dt < 0.002 and np.degrees(dr) < 0.2, (dt, np.degrees(dr))
    # the same robot poses from /joint_states through the built-in arm ('ur5e', as process and
    # the hand_eye node take it): the same X
    rc = main(["calibrate", "handeye", "--bag", str(bag), "--board", "chessboard:9x6:0.025",
               "--left-topic", "/stereo/left/image_raw", "--robot-pose", "joint_states",
               "--kinematics", "ur5e", "--no-html", "-o", str(tmp_path / "joints")])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    report = json.loads((tmp_path / "joints" / "report.json").read_text())
    assert "/joint_states" in report["input"]["pose_source"]
    dt, dr = transform_distance(X, load_hand_eye(tmp_path / "joints" / "hand_eye.yaml").transform)
    assert dt < 1e-6 and dr < 1e-6, (dt, dr)


def test_live_replay_with_tf_gives_the_offline_numbers(tf_bag, tmp_path, ros_context, executor,
                                                       spin_until, ros_env):
    pytest.importorskip("rclpy")
    from eye_in_hand.ros.tf import have_tf2_msgs

    if not have_tf2_msgs():
        pytest.skip("tf2_msgs not built (make venv)")
    from geometry_msgs.msg import PoseStamped
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from eye_in_hand.nodes.detect_triangulate import DetectTriangulateNode
    from eye_in_hand.nodes.hand_eye import HandEyeNode
    from eye_in_hand.ros.qos import RESULT_QOS
    from eye_in_hand.ros.stamps import header_stamp_ns

    bag, world = tf_bag
    # with a robot pose correction (systematic model): both paths apply it, the same way
    he = _hand_eye(tmp_path, world, _correction())
    off = tmp_path / "offline"
    assert main(["process", str(bag), "--hand-eye", str(he), "-o", str(off), "--quiet",
                 "--robot-pose", "tf", "--workers", "1"]) == 0
    offline = _base_points(off)
    plain = tmp_path / "plain"
    assert main(["process", str(bag), "--hand-eye", str(_hand_eye(plain, world)), "-o",
                 str(plain / "out"), "--quiet", "--robot-pose", "tf", "--workers", "1"]) == 0
    uncorrected = _base_points(plain / "out")
    assert set(uncorrected) == set(offline)
    moved = [np.linalg.norm(offline[k] - uncorrected[k]) for k in offline]
    assert min(moved) > 1e-4, moved           # the correction is applied offline
    detect = DetectTriangulateNode(context=ros_context, namespace="/stereo")
    hand_eye = HandEyeNode(context=ros_context, namespace="/stereo", parameter_overrides=[
        Parameter("hand_eye_file", value=str(he)), Parameter("robot_pose_source", value="tf"),
        Parameter("max_pose_wait_s", value=2.0)])
    listener = Node("tf_replay_listener", context=ros_context, namespace="/stereo")
    poses: list = []
    listener.create_subscription(PoseStamped, "target/pose", poses.append, RESULT_QOS)
    for n in (detect, hand_eye, listener):
        executor.add_node(n)
    proc = subprocess.Popen(
        [sys.executable, "-m", "eye_in_hand.cli", "play", str(bag), "--rate", "0.25",
         "--wait-for-subscribers", "30", "--topics", "/stereo/left/image_raw",
         "/stereo/right/image_raw", "/stereo/left/camera_info", "/stereo/right/camera_info",
         "/tf", "/tf_static"], env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        spin_until(executor, lambda: proc.poll() is not None, 90.0)
        spin_until(executor, lambda: len(poses) >= len(offline), 3.0)   # the last in flight
    finally:
        try:
            out, _ = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, _ = proc.communicate()
    assert proc.returncode == 0, out.decode(errors="replace")
    live = {header_stamp_ns(m): np.array([m.pose.position.x, m.pose.position.y,
                                          m.pose.position.z]) for m in poses}
    # every pose published live is the offline one (the live detector may drop a frame on a
    # busy machine, hand_eye must lose none for want of a TF pose, and none may differ)
    assert len(live) >= 5, (len(live), hand_eye.diag.causes)
    assert "no_robot_pose" not in hand_eye.diag.causes
    for stamp, p in live.items():
        np.testing.assert_allclose(p, offline[stamp], atol=1e-9)
