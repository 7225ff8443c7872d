"""eye-in-hand launch: supervised node processes, prefixed output, Ctrl-C, a dying node."""
from __future__ import annotations

import signal
import subprocess
import sys
import time

import numpy as np

from eye_in_hand.io.config import HandEyeCalibration, save_hand_eye
from eye_in_hand.launcher import NODES, node_command


def _params(tmp_path, hand_eye_file):
    text = (f"/**/hand_eye:\n  ros__parameters:\n    hand_eye_file: {hand_eye_file}\n"
            "/**/detect_triangulate:\n  ros__parameters:\n    method: dlt\n")
    path = tmp_path / "params.yaml"
    path.write_text(text)
    return path


def _launch(params, env, *extra):
    return subprocess.Popen([sys.executable, "-m", "eye_in_hand.cli", "launch", "--params",
                             str(params), "--skip", "stereo_capture", *extra], env=env,
                            text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)


def test_node_commands_put_topics_where_the_bags_have_them():
    cmds = {n.name: " ".join(node_command(n, "p.yaml")) for n in NODES}
    assert "__ns:=/stereo" in cmds["detect_triangulate"]
    assert "target/point:=/target/point" in cmds["detect_triangulate"]
    assert "targets/markers:=/targets/markers" in cmds["detect_triangulate"]
    assert "ee_pose:=/ee_pose" in cmds["stereo_capture"]
    assert "__ns:=/ " in cmds["hand_eye"] + " "
    ns = " ".join(node_command(NODES[1], "p.yaml", root_namespace="/robot1"))
    assert "__ns:=/robot1/stereo" in ns and "target/point:=/robot1/target/point" in ns


def test_node_processes_get_one_blas_thread_unless_the_user_chose(tmp_path):
    """Every node process runs with ``OPENBLAS_NUM_THREADS=1`` (idle OpenBLAS pool threads
    spin: docs/localization.md "Live latency"), also in calibration mode; a set value stays."""
    from eye_in_hand.launcher import Launcher

    params = tmp_path / "p.yaml"
    params.write_text("{}\n")
    assert Launcher(params, env={}).env["OPENBLAS_NUM_THREADS"] == "1"
    assert Launcher(params, env={}, calibrate=True).env["OPENBLAS_NUM_THREADS"] == "1"
    assert Launcher(params, env={"OPENBLAS_NUM_THREADS": "4"}).env["OPENBLAS_NUM_THREADS"] == "4"


def test_a_node_that_dies_stops_the_launch_with_its_name(tmp_path, ros_env):
    proc = _launch(_params(tmp_path, tmp_path / "missing.yaml"), ros_env, "--no-respawn")
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 1, out
    assert "[hand_eye]" in out and "missing.yaml" in out
    assert "hand_eye exited with code" in out and "restarting" not in out


def test_a_node_that_keeps_crashing_is_given_up_with_its_name(tmp_path, ros_env):
    proc = _launch(_params(tmp_path, tmp_path / "missing.yaml"), ros_env,
                   "--respawn-delay", "0.1", "--max-restarts", "2")
    out, _ = proc.communicate(timeout=90)
    assert proc.returncode == 1, out
    assert out.count("[launch] hand_eye exited with code 1; restarting in") == 2, out
    assert "restarting in 0.1 s (restart 1 of at most 2" in out
    assert "restarting in 0.2 s (restart 2 of at most 2" in out          # back-off doubles
    assert "hand_eye exited with code 1 (2 restart(s) within 60 s already): giving up" in out


class _Lines:
    """The launcher's output, read on a thread."""

    def __init__(self, proc):
        import threading

        self.lines: list[str] = []
        self.proc = proc
        self._th = threading.Thread(target=self._read, daemon=True)
        self._th.start()

    def _read(self):
        for line in self.proc.stdout:
            self.lines.append(line)

    @property
    def text(self):
        return "".join(self.lines)

    def wait_for(self, cond, timeout_s=60.0):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if cond(self.text):
                return True
            time.sleep(0.05)
        return False


def test_a_killed_node_is_restarted_and_messages_flow_again(tmp_path, ros_env, ros_context,
                                                            executor, spin_until, namespace):
    import os
    import re

    from geometry_msgs.msg import PointStamped, PoseStamped

    from eye_in_hand.ros.geometry import matrix_to_pose_stamped, xyz_to_point_stamped
    from eye_in_hand.ros.qos import RESULT_QOS, SENSOR_QOS

    he = tmp_path / "hand_eye.yaml"
    save_hand_eye(he, HandEyeCalibration("eye_in_hand", "tool0", "camera_left_optical_frame",
                                         np.eye(4)))
    proc = subprocess.Popen([sys.executable, "-m", "eye_in_hand.cli", "launch", "--params",
                             str(_params(tmp_path, he)), "--skip", "stereo_capture",
                             "detect_triangulate", "--namespace", namespace,
                             "--respawn-delay", "0.2"],
                            env=ros_env, text=True, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT)
    out = _Lines(proc)
    import rclpy

    node = rclpy.create_node("he_client", context=ros_context, namespace=namespace)
    executor.add_node(node)
    pub_pose = node.create_publisher(PoseStamped, "ee_pose", SENSOR_QOS)
    pub_point = node.create_publisher(PointStamped, "target/point", RESULT_QOS)
    got: list = []
    node.create_subscription(PoseStamped, "target/pose", got.append, RESULT_QOS)
    t0 = [1_700_000_000_000_000_000]

    def one_pose_through() -> bool:
        """Robot poses and a point in, a target/pose out; sent again every second (robot poses
        are best effort, and a node just started may still be matching)."""
        n = len(got)
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:
            spin_until(executor, lambda: pub_point.get_subscription_count() > 0
                       and pub_pose.get_subscription_count() > 0
                       and node.count_publishers("target/pose") > 0, 5.0)
            stamp = t0[0]
            t0[0] += 10**9
            for k in range(3):
                pub_pose.publish(matrix_to_pose_stamped(
                    np.eye(4), stamp_ns=stamp + k * 10_000_000, frame_id="base_link"))
            spin_until(executor, lambda: False, 0.1)
            pub_point.publish(xyz_to_point_stamped([0.0, 0.0, 0.5], stamp_ns=stamp + 5_000_000,
                                                   frame_id="camera_left_optical_frame"))
            if spin_until(executor, lambda: len(got) > n, 1.0):
                return True
        return False

    try:
        assert out.wait_for(lambda t: "[hand_eye]" in t and "started in" in t), out.text
        assert one_pose_through(), out.text
        pid = int(re.search(r"\[launch\] started hand_eye \(pid (\d+)\)", out.text).group(1))
        os.kill(pid, signal.SIGKILL)
        assert out.wait_for(lambda t: t.count("started in localization mode") == 2), out.text
        assert "[launch] hand_eye exited with code -9; restarting in 0.2 s" in out.text
        new = re.findall(r"\[launch\] started hand_eye \(pid (\d+)\)", out.text)
        assert len(new) == 2 and int(new[1]) != pid
        assert one_pose_through(), out.text             # the pipeline resumed
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)
    assert proc.returncode == 0, out.text


def test_ctrl_c_stops_every_node_cleanly(tmp_path, ros_env):
    he = tmp_path / "hand_eye.yaml"
    save_hand_eye(he, HandEyeCalibration("eye_in_hand", "tool0", "camera_left_optical_frame",
                                         np.eye(4)))
    proc = _launch(_params(tmp_path, he), ros_env)
    lines = []
    deadline = time.monotonic() + 60
    assert proc.stdout is not None
    while time.monotonic() < deadline:                 # wait until both nodes report started
        line = proc.stdout.readline()
        lines.append(line)
        text = "".join(lines)
        if "[hand_eye]" in text and "started" in text and "[detect_triangulate]" in text \
                and "detecting" in text:
            break
    proc.send_signal(signal.SIGINT)
    rest, _ = proc.communicate(timeout=60)
    assert proc.returncode == 0, "".join(lines) + rest


def test_calibration_mode_commands_remap_the_camera_images():
    from eye_in_hand.launcher import CALIBRATION_NODES

    assert [n.name for n in CALIBRATION_NODES] == ["stereo_capture", "hand_eye"]
    cmd = " ".join(node_command(CALIBRATION_NODES[1], "p.yaml", root_namespace="/cell"))
    assert "left/image_raw:=/cell/stereo/left/image_raw" in cmd
    assert "right/image_raw:=/cell/stereo/right/image_raw" in cmd
    assert "image_raw:=/cell/stereo/left/image_raw" in cmd
    assert cmd.endswith("-p mode:=calibration")       # after --params-file: it wins


def test_launch_calibrate_starts_hand_eye_in_calibration_mode(tmp_path, ros_env, ros_context,
                                                              executor, namespace, spin_until):
    """`eye-in-hand launch --calibrate`: hand_eye offers the calibration services and reads
    the camera's images under <ns>/stereo; the parameter file needs no 'mode'."""
    from rclpy.node import Node
    from std_srvs.srv import Trigger

    from eye_in_hand.sim import World

    World.default().with_image_size(320, 180).rig.save(tmp_path / "calib")
    params = tmp_path / "cal.yaml"
    params.write_text(f"/**/hand_eye:\n  ros__parameters:\n    calibration_dir: "
                      f"{tmp_path / 'calib'}\n    output_dir: {tmp_path / 'out'}\n")
    proc = subprocess.Popen([sys.executable, "-m", "eye_in_hand.cli", "launch", "--calibrate",
                             "--params", str(params), "--skip", "stereo_capture",
                             "--namespace", namespace, "--duration", "30"], env=ros_env,
                            text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        probe = Node("probe", context=ros_context)
        executor.add_node(probe)
        client = probe.create_client(Trigger, f"{namespace}/hand_eye/reset")
        ok = spin_until(executor, lambda: client.service_is_ready() and probe.count_subscribers(
            f"{namespace}/stereo/left/image_raw") == 1, 25.0)
        assert ok, "hand_eye in calibration mode did not come up"
        fut = client.call_async(Trigger.Request())
        assert spin_until(executor, fut.done, 10.0) and fut.result().success
    finally:
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
    assert "started in calibration mode" in out, out
    assert "Traceback" not in out, out


def test_calibration_and_hand_eye_flags_become_node_parameters(tmp_path):
    """``launch --calibration DIR --hand-eye FILE`` set the nodes' parameters after the
    parameter file, quoted as strings; a missing folder or file is one error line before any
    node starts."""
    import argparse

    from eye_in_hand.commands.launch import _overrides
    from eye_in_hand.errors import InputError

    spec = next(n for n in NODES if n.name == "hand_eye")
    cmd = node_command(spec, tmp_path / "p.yaml", overrides=[("hand_eye_file", "1234"),
                                                            ("x", "it's")])
    assert cmd[cmd.index("--params-file") + 2:][:4] == [
        "-p", "hand_eye_file:='1234'", "-p", "x:='it''s'"]      # a string, not the int 1234

    calib = tmp_path / "calib"
    calib.mkdir()
    args = argparse.Namespace(calibration=str(calib), hand_eye=None, calibrate=False)
    try:
        _overrides(args)
    except InputError as exc:
        assert "--calibration" in str(exc) and "left.yaml + right.yaml" in str(exc)
    else:
        raise AssertionError("a folder without left.yaml + right.yaml was accepted")
    for side in ("left", "right"):
        (calib / f"{side}.yaml").write_text("{}")
    he = tmp_path / "hand_eye.yaml"
    he.write_text("{}")
    args = argparse.Namespace(calibration=str(calib), hand_eye=str(he), calibrate=False)
    assert _overrides(args) == {"detect_triangulate": [("calibration_dir", str(calib.resolve()))],
                                "hand_eye": [("hand_eye_file", str(he.resolve()))]}
    args.calibrate = True          # calibration mode: hand_eye reads the stereo calibration
    assert ("calibration_dir", str(calib.resolve())) in _overrides(args)["hand_eye"]
    args.hand_eye = str(tmp_path / "missing.yaml")
    try:
        _overrides(args)
    except InputError as exc:
        assert "--hand-eye" in str(exc) and "file not found" in str(exc)
    else:
        raise AssertionError("a missing hand_eye.yaml was accepted")


def test_launch_composed_runs_the_chain_in_one_process(tmp_path, ros_env, ros_context, executor,
                                                       spin_until, namespace):
    """``launch --composed``: detect_triangulate + hand_eye in one process (``localize``),
    started with the launcher's namespace, parameter file and --calibration/--hand-eye; images
    and robot poses in, the target in the base frame out, and the camera-frame topics still
    there for other subscribers."""
    from geometry_msgs.msg import PointStamped, PoseStamped
    from sensor_msgs.msg import Image

    from eye_in_hand.core.localization import target_in_base
    from eye_in_hand.ros.geometry import matrix_to_pose_stamped
    from eye_in_hand.ros.images import numpy_to_image
    from eye_in_hand.ros.qos import RESULT_QOS, SENSOR_QOS
    from test.nodes.test_every_target import BOTH, CAM, EE_T_CAM, RIG, T0, TARGETS, _robot_pose

    RIG.save(tmp_path / "calib")
    he = tmp_path / "hand_eye.yaml"
    save_hand_eye(he, HandEyeCalibration("eye_in_hand", "tool0", CAM, EE_T_CAM))
    params = tmp_path / "params.yaml"
    params.write_text("/**/hand_eye:\n  ros__parameters:\n    hand_eye_file: /nonexistent\n"
                      "/**/detect_triangulate:\n  ros__parameters:\n    sync.slop_s: 0.0\n"
                      f"    frame_id: {CAM}\n")
    proc = subprocess.Popen([sys.executable, "-m", "eye_in_hand.cli", "launch", "--params",
                             str(params), "--skip", "stereo_capture", "--composed",
                             "--namespace", namespace, "--calibration", str(tmp_path / "calib"),
                             "--hand-eye", str(he), "--no-respawn"],
                            env=ros_env, text=True, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT)
    out = _Lines(proc)
    import rclpy

    node = rclpy.create_node("io", context=ros_context, namespace=namespace)
    executor.add_node(node)
    pub_l = node.create_publisher(Image, "stereo/left/image_raw", SENSOR_QOS)
    pub_r = node.create_publisher(Image, "stereo/right/image_raw", SENSOR_QOS)
    pub_ee = node.create_publisher(PoseStamped, "ee_pose", SENSOR_QOS)
    poses: list = []
    points: list = []
    node.create_subscription(PoseStamped, "target/pose", poses.append, RESULT_QOS)
    node.create_subscription(PointStamped, "target/point", points.append, RESULT_QOS)
    try:
        assert out.wait_for(lambda t: "[localize]" in t and "started in localization" in t), \
            out.text
        assert "[launch] started localize" in out.text and "started detect" not in out.text
        assert spin_until(executor, lambda: pub_l.get_subscription_count() > 0
                          and pub_ee.get_subscription_count() > 0
                          and node.count_publishers("target/pose") > 0, 30.0), out.text
        spin_until(executor, lambda: False, 0.5)
        stamp = T0
        deadline = time.monotonic() + 40.0
        while not poses and time.monotonic() < deadline:   # images are reliable, poses not
            for dt in (-10_000_000, 10_000_000):
                pub_ee.publish(matrix_to_pose_stamped(_robot_pose(stamp + dt),
                                                      stamp_ns=stamp + dt, frame_id="base_link"))
            pub_l.publish(numpy_to_image(BOTH[0], "bgr8", stamp_ns=stamp, frame_id=CAM))
            pub_r.publish(numpy_to_image(BOTH[1], "bgr8", stamp_ns=stamp, frame_id=CAM))
            spin_until(executor, lambda: bool(poses), 2.0)
            stamp += 50_000_000
        assert poses, out.text
        from eye_in_hand.ros.stamps import header_stamp_ns

        s = header_stamp_ns(poses[0])
        got = np.array([poses[0].pose.position.x, poses[0].pose.position.y,
                        poses[0].pose.position.z])
        truth, _ = target_in_base(_robot_pose(s), EE_T_CAM, TARGETS["red"][0])
        assert np.linalg.norm(got - truth) < 3e-3
        assert spin_until(executor, lambda: bool(points), 5.0)   # camera-frame topic too
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)
    assert proc.returncode == 0, out.text
