"""In-process tests of the detect_triangulate node: points, bad input, parameters."""
from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import PointStamped  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image  # noqa: E402

from eye_in_hand.core.camera import CameraModel, StereoRig  # noqa: E402
from eye_in_hand.errors import ConfigError  # noqa: E402
from eye_in_hand.nodes.detect_triangulate import DetectTriangulateNode  # noqa: E402
from eye_in_hand.ros.camera_info import model_to_camera_info
from eye_in_hand.ros.images import numpy_to_image
from eye_in_hand.ros.qos import RESULT_QOS, SENSOR_QOS  # noqa: E402
from eye_in_hand.sim.sphere import render_sphere

PARAM_FILE = Path(__file__).resolve().parents[2] / "config" / "detect_triangulate.yaml"
W, H = 640, 360
K = np.array([[450.0, 0.0, 320.0], [0.0, 452.0, 180.0], [0.0, 0.0, 1.0]])
X_TRUE = np.array([0.04, -0.02, 0.4])
STAMP0 = 1_700_000_000_000_000_000


def make_rig():
    left = CameraModel(K, [-0.2, 0.08, 0.0, 0.0, 0.0], W, H, name="left")
    right = CameraModel(K, [-0.19, 0.07, 0.0, 0.0, 0.0], W, H, name="right")
    R = cv2.Rodrigues(np.array([0.005, -0.01, 0.0]))[0]
    return StereoRig(left, right, R, [-0.06, 0.0, 0.0]).rectified()


RIG = make_rig()


def render_pair():
    out = []
    for cam, T in ((RIG.left, np.eye(4)), (RIG.right, RIG.right_T_left)):
        img = np.full((H, W, 3), (90, 110, 100), np.uint8)
        render_sphere(img, cam, T[:3, :3] @ X_TRUE + T[:3, 3], 0.02, (30, 30, 200))
        out.append(img)
    return out


LEFT, RIGHT = render_pair()


class Feeder:
    """Publishes stereo pairs (and camera_info) from its own node, one per call."""

    def __init__(self, context, namespace):
        self.node = Node("feeder", context=context, namespace=namespace)
        self.pubs = {n: self.node.create_publisher(t, n, SENSOR_QOS) for n, t in (
            ("left/image_raw", Image), ("right/image_raw", Image),
            ("left/camera_info", CameraInfo), ("right/camera_info", CameraInfo))}
        self.points: list[PointStamped] = []
        self.debug: list[Image] = []
        self.diags: list[DiagnosticArray] = []
        self.node.create_subscription(PointStamped, "target/point", self.points.append,
                                      RESULT_QOS)
        self.node.create_subscription(DiagnosticArray, "diagnostics", self.diags.append,
                                      RESULT_QOS)
        self.k = 0

    def publish(self, left=LEFT, right=RIGHT, *, info=True, skew_ns=0, left_msg=None,
                right_msg=None, frame="cam_left"):
        stamp = STAMP0 + self.k * 50_000_000
        self.k += 1
        lm = left_msg or numpy_to_image(left, "bgr8", stamp_ns=stamp, frame_id=frame)
        rm = right_msg or numpy_to_image(right, "bgr8", stamp_ns=stamp + skew_ns)
        lm.header.stamp.sec, lm.header.stamp.nanosec = divmod(stamp, 10**9)
        rm.header.stamp.sec, rm.header.stamp.nanosec = divmod(stamp + skew_ns, 10**9)
        if info:
            self.pubs["left/camera_info"].publish(model_to_camera_info(RIG.left, stamp_ns=stamp))
            self.pubs["right/camera_info"].publish(model_to_camera_info(RIG.right,
                                                                        stamp_ns=stamp))
        self.pubs["left/image_raw"].publish(lm)
        self.pubs["right/image_raw"].publish(rm)
        return stamp


def _thread_names() -> set[str]:
    """The OS names of this process's threads (Linux /proc)."""
    names = set()
    for task in Path("/proc/self/task").iterdir():
        try:
            names.add((task / "comm").read_text().strip())
        except OSError:        # a thread that ended meanwhile
            pass
    return names


def start(executor, ros_context, namespace, **params):
    overrides = [Parameter(k, value=v) for k, v in params.items()]
    node = DetectTriangulateNode(context=ros_context, namespace=namespace,
                                 parameter_overrides=overrides)
    feeder = Feeder(ros_context, namespace)
    executor.add_node(node)
    executor.add_node(feeder.node)
    return node, feeder


def pump(executor, spin_until, feeder, cond, timeout_s=15.0, **kw):
    """Publish a pair every 0.1 s until cond() holds."""
    last = [-1.0]
    import time

    def step():
        if cond():
            return True
        now = time.monotonic()
        if now - last[0] > 0.1:
            last[0] = now
            feeder.publish(**kw)
        return False

    return spin_until(executor, step, timeout_s)


def test_publishes_the_target_point_at_the_image_stamp(executor, ros_context, namespace,
                                                       spin_until):
    node, feeder = start(executor, ros_context, namespace, **{"sync.slop_s": 0.0})
    assert pump(executor, spin_until, feeder, lambda: len(feeder.points) >= 2)
    for p in feeder.points:
        stamp = p.header.stamp.sec * 10**9 + p.header.stamp.nanosec
        assert (stamp - STAMP0) % 50_000_000 == 0
        assert p.header.frame_id == "cam_left"
        xyz = np.array([p.point.x, p.point.y, p.point.z])
        assert np.linalg.norm(xyz - X_TRUE) < 1e-3, xyz - X_TRUE
    assert node.diag.counter("detections") >= 2 and node.diag.causes == {}
    if Path("/proc/self/task").is_dir():   # the worker's CPU shows apart (top -H)
        assert "detect_worker" in _thread_names()


def test_bad_input_is_counted_and_the_node_keeps_running(executor, ros_context, namespace,
                                                         spin_until):
    node, feeder = start(executor, ros_context, namespace, frame_id="optical")
    # 1. no camera_info yet
    assert pump(executor, spin_until, feeder, lambda: "no_camera_info" in node.diag.causes,
                info=False)
    # 2. wrong encoding
    mono = numpy_to_image(cv2.cvtColor(LEFT, cv2.COLOR_BGR2GRAY), "mono8")
    assert pump(executor, spin_until, feeder, lambda: "bad_encoding" in node.diag.causes,
                left_msg=mono)
    # 3. size disagreeing with camera_info
    small = np.ascontiguousarray(RIGHT[:200, :300])
    assert pump(executor, spin_until, feeder, lambda: "size_mismatch" in node.diag.causes,
                right=small)
    # 4. truncated data
    def truncated():
        m = numpy_to_image(LEFT, "bgr8")
        m.data = m.data[: len(m.data) // 2]
        return m
    assert pump(executor, spin_until, feeder, lambda: "bad_image" in node.diag.causes,
                left_msg=truncated())
    # 5. unsynchronised pairs (right 20 ms late, slop 5 ms)
    assert pump(executor, spin_until, feeder, lambda: "unsynchronised" in node.diag.causes,
                skew_ns=20_000_000)
    assert feeder.points == []
    # still alive: a good pair gives a point, in the frame set by the parameter
    assert pump(executor, spin_until, feeder, lambda: len(feeder.points) >= 1)
    assert feeder.points[0].header.frame_id == "optical"
    # and diagnostics report the causes
    assert spin_until(executor, lambda: any(
        kv.key == "problem: bad_encoding" for d in feeder.diags for s in d.status
        for kv in s.values), 5.0)


def test_calibration_files_and_debug_image(executor, ros_context, namespace, spin_until,
                                           tmp_path):
    RIG.save(tmp_path)
    (tmp_path / "stereo.yaml").unlink()  # ROS's two files alone
    node, feeder = start(executor, ros_context, namespace, calibration_dir=str(tmp_path),
                         **{"debug_image.max_rate_hz": 100.0})
    debug: list[Image] = []
    feeder.node.create_subscription(Image, "target/debug_image", debug.append, SENSOR_QOS)
    assert pump(executor, spin_until, feeder,
                lambda: len(feeder.points) >= 1 and len(debug) >= 1, info=False)
    p = feeder.points[0]
    assert np.linalg.norm(np.array([p.point.x, p.point.y, p.point.z]) - X_TRUE) < 1e-3
    assert (debug[0].width, debug[0].height, debug[0].encoding) == (W, H // 2, "bgr8")


def test_no_debug_image_without_subscribers(executor, ros_context, namespace, spin_until):
    node, feeder = start(executor, ros_context, namespace)
    assert pump(executor, spin_until, feeder, lambda: len(feeder.points) >= 2)
    assert node.targets.last_debug == -math.inf


def test_every_target_gets_its_own_topic_when_several_are_configured(
        executor, ros_context, namespace, spin_until):
    node, feeder = start(executor, ros_context, namespace, target_names=["green", "red"],
                         **{"targets.green.lower": [45, 120, 70],
                            "targets.green.upper": [75, 255, 255]})
    red: list[PointStamped] = []
    feeder.node.create_subscription(PointStamped, "targets/red/point", red.append, RESULT_QOS)
    assert pump(executor, spin_until, feeder, lambda: len(red) >= 1)
    assert feeder.points == []  # target/point carries the first target (green): not in view
    assert np.linalg.norm(np.array([red[0].point.x, red[0].point.y, red[0].point.z])
                          - X_TRUE) < 1e-3
    assert node.diag.counter("detections") == 0


@pytest.mark.parametrize("params, match", [
    ({"method": "magic"}, "method"),
    ({"pixel_sigma": -1.0}, "pixel_sigma"),
    ({"target_names": ["a b"]}, "target_names"),
    ({"targets.red.lower": [200, 0, 0]}, "targets.red"),
])
def test_bad_parameters_stop_the_node_with_the_name(ros_context, namespace, params, match):
    with pytest.raises(ConfigError, match=match):
        DetectTriangulateNode(context=ros_context, namespace=namespace,
                              parameter_overrides=[Parameter(k, value=v)
                                                   for k, v in params.items()])


def test_node_process_publishes_across_dds(ros_context, executor, namespace, spin_until,
                                           ros_env, tmp_path):
    """The real node process (python -m ...) with calibration files, fed from this process."""
    import subprocess
    import sys

    RIG.save(tmp_path)
    proc = subprocess.Popen(
        [sys.executable, "-m", "eye_in_hand.nodes.detect_triangulate", "--ros-args",
         "-r", f"__ns:={namespace}", "--params-file", str(PARAM_FILE),
         "-p", f"calibration_dir:={tmp_path}"],
        env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        feeder = Feeder(ros_context, namespace)
        executor.add_node(feeder.node)
        ok = pump(executor, spin_until, feeder, lambda: len(feeder.points) >= 1,
                  timeout_s=30.0, info=False)
        if not ok:
            proc.send_signal(2)
            pytest.fail(f"no point from the node process; its output:\n{proc.communicate()[0]}")
        p = feeder.points[0]
        assert np.linalg.norm(np.array([p.point.x, p.point.y, p.point.z]) - X_TRUE) < 1e-3
        assert proc.poll() is None
    finally:
        proc.send_signal(2)  # SIGINT: the node shuts down cleanly
        try:
            out, _ = proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, _ = proc.communicate()
    assert proc.returncode == 0, out
    assert "Traceback" not in out, out


def test_point_cov_and_a_time_jump_back_resets_pairing(executor, ros_context, namespace,
                                                       spin_until):
    from geometry_msgs.msg import PoseWithCovarianceStamped

    node, feeder = start(executor, ros_context, namespace, **{"sync.slop_s": 0.0})
    covs = []
    feeder.node.create_subscription(PoseWithCovarianceStamped, "target/point_cov", covs.append,
                                    RESULT_QOS)
    assert pump(executor, spin_until, feeder, lambda: len(feeder.points) >= 2 and len(covs) >= 2)
    c = covs[0]
    assert any(c.header.stamp == p.header.stamp for p in feeder.points)
    cov = np.asarray(c.pose.covariance).reshape(6, 6)[:3, :3]
    assert np.all(np.linalg.eigvalsh(cov) > 0) and np.allclose(cov, cov.T)
    assert c.pose.pose.position.z == pytest.approx(X_TRUE[2], abs=1e-3)
    # A bag restarted with --loop: stamps jump 5 s back. Pairing restarts, nothing is stale.
    n = len(feeder.points)
    feeder.k = -100
    assert pump(executor, spin_until, feeder, lambda: len(feeder.points) >= n + 2)
    assert node.diag.counter("time_jumps") >= 1
    assert "stale_stamp" not in node.diag.causes


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux /proc")
def test_node_process_uses_one_blas_thread():
    """The node's process loads OpenBLAS with one thread (its idle pool threads spin and cost
    the live pipeline most of a core), unless the user set OPENBLAS_NUM_THREADS."""
    import os
    import subprocess
    import sys

    code = ("import os, eye_in_hand.nodes.detect_triangulate, numpy, scipy.linalg; "
            "print(os.environ.get('OPENBLAS_NUM_THREADS', 'unset'), "
            "len(os.listdir('/proc/self/task')))")

    def run(**extra):
        env = {k: v for k, v in os.environ.items()
               if k not in ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")}
        env.update(extra)
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                             text=True, check=True).stdout.split()
        return out[0], int(out[1])

    value, threads = run()
    assert threads == run(OPENBLAS_NUM_THREADS="1")[1]   # no BLAS pool threads
    assert value == "1"
    assert run(OPENBLAS_NUM_THREADS="2")[0] == "2"       # the user's choice is kept


def test_stale_stamps_are_in_the_one_loss_total(executor, ros_context, namespace, spin_until):
    """A replay right after a run repeats stamps: those images are dropped as stale_stamp and
    counted in ``frames_lost`` (the loss total on diagnostics), not only warned about."""
    node, feeder = start(executor, ros_context, namespace, **{"sync.slop_s": 0.0})
    assert pump(executor, spin_until, feeder, lambda: len(feeder.points) >= 2)
    feeder.k -= 2                      # the next two pairs repeat stamps already seen
    n = node.diag.counter("sync_unpaired_left")
    assert pump(executor, spin_until, feeder,
                lambda: node.diag.counter("sync_unpaired_left") >= n + 2)
    assert node.diag.counter("time_jumps") == 0 and "stale_stamp" in node.diag.causes
    spin_until(executor, lambda: node.diag.snapshot().gauges.get("sync_stale", 0) >= 2, 5.0)
    gauges = node.diag.snapshot().gauges
    lost_now = sum(node.diag.counter(k) for k in ("sync_unpaired_left", "sync_unpaired_right",
                                                   "dropped_pairs", "failed_pairs"))
    assert 2 <= gauges["sync_stale"] <= gauges["frames_lost"] <= lost_now


def test_sync_slop_is_in_seconds(ros_context, namespace):
    """``sync.slop_s`` is seconds: 0.004 pairs frames up to 4 ms apart."""
    node = DetectTriangulateNode(context=ros_context, namespace=namespace,
                                 parameter_overrides=[Parameter("sync.slop_s", value=0.004)])
    try:
        assert node.intake.sync.slop_ns == 4_000_000
        sync = node.intake.sync
        pairs = sync.push_left(10**9, None) + sync.push_right(10**9 + 3_900_000, None)
        pairs += sync.push_left(2 * 10**9, None)
        assert len(pairs) == 1 and pairs[0].skew_ns == 3_900_000
    finally:
        node.destroy_node()
