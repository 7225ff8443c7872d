"""hand_eye calibration mode in-process: capture from a streaming camera, refusals, typed
services, status, and a compute that leaves the node responsive."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rclpy")

from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from eye_in_hand.nodes.hand_eye import HandEyeNode  # noqa: E402
from eye_in_hand.ros.geometry import matrix_to_pose_stamped
from eye_in_hand.ros.images import numpy_to_image
from eye_in_hand.ros.qos import LATCHED_QOS, SENSOR_QOS  # noqa: E402

T0 = 1_700_000_000_000_000_000
MS = 1_000_000


class _Cell:
    """A hand_eye node in calibration mode, a camera and a robot driver stand-in, in-process."""

    def __init__(self, tmp_path, ros_context, executor, namespace, spin_until, **params):
        from geometry_msgs.msg import PoseStamped
        from sensor_msgs.msg import Image
        from std_srvs.srv import Trigger

        from eye_in_hand.sim import World

        self.world = World.default().with_image_size(640, 360)
        self.world.rig.save(tmp_path / "calib")
        self.out = tmp_path / "he_out"
        overrides = [Parameter("mode", value="calibration"),
                     Parameter("calibration_dir", value=str(tmp_path / "calib")),
                     Parameter("output_dir", value=str(self.out)),
                     Parameter("debug_image_rate_hz", value=50.0)]
        overrides += [Parameter(k, value=v) for k, v in params.items()]
        self.node = HandEyeNode(context=ros_context, namespace=namespace,
                                parameter_overrides=overrides)
        self.io = Node("he_cal_io", context=ros_context, namespace=namespace)
        self.executor, self.spin_until = executor, spin_until
        executor.add_node(self.node)
        executor.add_node(self.io)
        self.pub_l = self.io.create_publisher(Image, "left/image_raw", SENSOR_QOS)
        self.pub_r = self.io.create_publisher(Image, "right/image_raw", SENSOR_QOS)
        self.pub_pose = self.io.create_publisher(PoseStamped, "ee_pose", SENSOR_QOS)
        self.triggers = {n: self.io.create_client(Trigger, f"hand_eye/{n}") for n in
                         ("capture", "compute", "save", "reset")}
        self.Trigger = Trigger
        self.clock_ns = T0
        self.frames_by_stamp: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        assert spin_until(executor, lambda: all(c.service_is_ready() for c in
                                                self.triggers.values())
                          and self.pub_l.get_subscription_count()
                          and self.pub_pose.get_subscription_count(), 10.0)

    def spin(self, cond, timeout=30.0):
        return self.spin_until(self.executor, cond, timeout)

    def render(self, q, k):
        frame = self.world.render(q, seed=k, noise_sigma=1.0, supersample=2)
        return frame.left, frame.right

    def show(self, q, k, *, moving=False, poses_before_ms=300, poses_after_ms=300,
             images=None, pose_lag_ms=0):
        """One image pair at a new stamp, with robot poses at 40 Hz around it."""
        # a camera and a driver on the node's clock: the pair is exposed now
        stamp = self.clock_ns = max(self.node.get_clock().now().nanoseconds,
                                    self.clock_ns + 400 * MS)
        base_T_ee = self.world.arm.fk(q)
        for dt in range(-poses_before_ms, poses_after_ms + 1, 25):
            T = base_T_ee.copy()
            if moving:
                T[0, 3] += dt * 1e-5                       # 10 mm/s
            self.pub_pose.publish(matrix_to_pose_stamped(T, stamp_ns=stamp + dt * MS,
                                                         frame_id="base_link"))
        left, right = images if images is not None else self.render(q, k)
        self.pub_l.publish(numpy_to_image(left, "bgr8", stamp_ns=stamp))
        self.pub_r.publish(numpy_to_image(right, "bgr8", stamp_ns=stamp))
        return stamp

    def call_async(self, client, request=None):
        return client.call_async(request if request is not None else client.srv_type.Request())

    def trigger(self, name):
        fut = self.call_async(self.triggers[name])
        assert self.spin(fut.done, 60.0)
        return fut.result()

    def capture_at(self, q, k, **kw):
        """Ask, then let the camera and robot stream: the answer comes from the next pair."""
        fut = self.call_async(self.triggers["capture"])
        self.spin(lambda: bool(self.node.calibration_mode._waiters), 5.0)
        self.show(q, k, **kw)
        assert self.spin(fut.done, 30.0)
        return fut.result()


@pytest.fixture
def cell(tmp_path, ros_context, executor, namespace, spin_until):
    return _Cell(tmp_path, ros_context, executor, namespace, spin_until, capture_timeout_s=3.0)


def test_capture_refusals_and_trigger_flow(cell):
    """Moving, duplicate, board not seen, no pose after the image; then capture, compute,
    save, reset, all through std_srvs/Trigger as from a shell."""
    from eye_in_hand.core.transforms import transform_distance
    from eye_in_hand.io.config import load_hand_eye
    from eye_in_hand.sim.scenarios import calibration_poses

    poses = calibration_poses(cell.world, 6, seed=0)
    res = cell.capture_at(poses[0], 0, moving=True)
    assert not res.success and "refused (moving)" in res.message
    blank = np.full((360, 640, 3), 90, np.uint8)
    res = cell.capture_at(poses[0], 0, images=(blank, blank))
    assert not res.success and "refused (board_not_seen)" in res.message
    for k, q in enumerate(poses):
        res = cell.capture_at(q, k)
        assert res.success, res.message
    res = cell.capture_at(poses[-1], 99)
    assert not res.success and "refused (duplicate)" in res.message
    assert "already taken as sample_005" in res.message
    # a pair newer than every robot pose that ever comes: no_pose after the timeout
    res = cell.capture_at(poses[0], 0, poses_after_ms=0)
    assert not res.success and "refused (no_pose)" in res.message
    session = cell.node.calibration_mode.session
    assert len(session.records) == 6
    assert [r.split(":")[0] for _, r in session.skipped] == [
        "moving", "board_not_seen", "duplicate", "no_pose"]
    res = cell.trigger("compute")
    assert res.success, res.message
    dt, dr = transform_distance(session.result.X, cell.world.ee_T_cam)
    assert dt < 1e-3 and np.degrees(dr) < 0.1, (dt, np.degrees(dr))
    res = cell.trigger("save")
    assert res.success, res.message
    saved = load_hand_eye(cell.out / "hand_eye.yaml")
    assert np.allclose(saved.transform, session.result.X, atol=1e-9)
    res = cell.trigger("reset")
    assert res.success and "forgot 6 samples" in res.message
    res = cell.trigger("compute")
    assert not res.success and "need at least 3" in res.message


def test_capture_waits_for_late_robot_poses(cell):
    """Poses arrive after the image (a driver 300 ms behind): the capture waits, then takes it."""
    from eye_in_hand.sim.scenarios import calibration_poses

    q = calibration_poses(cell.world, 1, seed=0)[0]
    fut = cell.call_async(cell.triggers["capture"])
    cell.spin(lambda: bool(cell.node.calibration_mode._waiters), 5.0)
    stamp = cell.show(q, 0, poses_after_ms=0)          # poses up to the image stamp only
    cell.spin(lambda: False, 0.5)
    assert not fut.done()                              # waiting for the window's poses
    T = cell.world.arm.fk(q)
    for dt in range(25, 301, 25):
        cell.pub_pose.publish(matrix_to_pose_stamped(T, stamp_ns=stamp + dt * MS,
                                                     frame_id="base_link"))
    assert cell.spin(fut.done, 30.0)
    assert fut.result().success, fut.result().message


def test_no_image_after_the_request_times_out(tmp_path, ros_context, executor, namespace,
                                              spin_until):
    c = _Cell(tmp_path, ros_context, executor, namespace, spin_until, capture_timeout_s=0.3)
    res = c.trigger("capture")
    assert not res.success and "refused (no_image)" in res.message
    # the refusal names the topics as resolved (namespace, remapping)
    assert f"{namespace}/left/image_raw, {namespace}/right/image_raw" in res.message


def test_typed_services_status_and_debug_image(cell):
    pytest.importorskip("eye_in_hand_interfaces")
    from geometry_msgs.msg import PoseArray
    from sensor_msgs.msg import Image

    from eye_in_hand.sim.scenarios import calibration_poses
    from eye_in_hand_interfaces.msg import CalibrationStatus
    from eye_in_hand_interfaces.srv import (
        Capture,
        Compute,
        GetStatus,
        ListSamples,
        Load,
        RemoveSample,
        Save,
    )

    ns = cell.node.get_fully_qualified_name()
    clients = {name: cell.io.create_client(typ, f"{ns}/calibration/{name}") for name, typ in (
        ("capture", Capture), ("list_samples", ListSamples), ("remove_sample", RemoveSample),
        ("compute", Compute), ("save", Save), ("load", Load), ("get_status", GetStatus))}
    statuses, nexts, debug = [], [], []
    cell.io.create_subscription(CalibrationStatus, f"{ns}/calibration_status", statuses.append,
                                LATCHED_QOS)
    cell.io.create_subscription(PoseArray, f"{ns}/next_poses", nexts.append, LATCHED_QOS)
    cell.io.create_subscription(Image, f"{ns}/debug_image", debug.append, 10)
    assert cell.spin(lambda: all(c.service_is_ready() for c in clients.values())
                     and statuses, 10.0)
    assert statuses[-1].samples == 0 and not statuses[-1].good_enough

    def call(service, **fields):
        req = clients[service].srv_type.Request(**fields)
        fut = clients[service].call_async(req)
        assert cell.spin(fut.done, 60.0)
        return fut.result()

    poses = calibration_poses(cell.world, 7, seed=1)
    for k, q in enumerate(poses):
        fut = clients["capture"].call_async(Capture.Request())
        cell.spin(lambda: bool(cell.node.calibration_mode._waiters), 5.0)
        cell.show(q, k)
        assert cell.spin(fut.done, 30.0)
        res = fut.result()
        assert res.success and res.reason == "" and res.index == k, res.message
        assert res.sample.name == f"sample_{k:03d}" and res.sample.corners == 2 * 54
        assert 0 < res.sample.reprojection_error_px < 1.0
        assert res.sample.board_pose.position.z > 0.1
    assert debug and debug[-1].width == 640                     # drawn while subscribed
    # the status refresh runs on the worker: wait for the estimate of all 7 samples
    assert cell.spin(lambda: statuses[-1].samples == 7 and statuses[-1].has_estimate
                     and nexts and len(nexts[-1].poses) == 3, 60.0)
    st = statuses[-1]
    assert st.rotation_spread_deg > 10 and st.std_mm > 0 and "of 10 samples" in st.problems[0]
    assert nexts and len(nexts[-1].poses) == 3 and nexts[-1].header.frame_id == "base_link"
    assert len(st.next_poses.poses) == 3
    listed = call("list_samples")
    assert [s.index for s in listed.samples] == list(range(7))
    res = call("remove_sample", index=2)
    assert res.success and res.samples == 6 and "sample_002" in res.message
    res = call("remove_sample", name="sample_009")
    assert not res.success and "no sample named 'sample_009'" in res.message
    assert [s.name for s in call("list_samples").samples] == [
        "sample_000", "sample_001", "sample_003", "sample_004", "sample_005", "sample_006"]
    res = call("compute")
    assert res.success, res.message
    assert res.selected_method and len(res.scores) >= 6
    assert {s.method for s in res.scores} >= {"tsai", "park", "refined"}
    assert res.transform.header.frame_id == "tool0"
    assert res.std_mm > 0 and np.any(np.asarray(res.covariance) != 0)
    out = cell.out.parent / "typed_save"
    res = call("save", path=str(out))
    assert res.success and str(out / "hand_eye.yaml") in res.files
    res = call("save", path=str(out))              # its own save: replaced
    assert res.success
    other = cell.out.parent / "someone_elses"
    other.mkdir()
    (other / "hand_eye.yaml").write_text("an earlier calibration")
    res = call("save", path=str(other))
    assert not res.success and "overwrite: true" in res.message
    assert (other / "hand_eye.yaml").read_text() == "an earlier calibration"
    res = call("load", path=str(out))
    assert res.success and "loaded" in res.message
    res = call("load", path=str(cell.out.parent / "missing"))
    assert not res.success and "load failed" in res.message
    st = call("get_status").status
    assert st.samples == 6 and st.has_estimate


def test_compute_leaves_the_node_responsive(cell):
    """While compute runs on the worker, images are still taken in and diagnostics sent."""
    from diagnostic_msgs.msg import DiagnosticArray

    from eye_in_hand.core.handeye.synthetic import make_problem

    problem = make_problem(25, seed=2, stereo=True)     # a few seconds of compute
    session = cell.node.calibration_mode.session
    session.add_samples(problem.samples)
    diags = []
    cell.io.create_subscription(DiagnosticArray, "diagnostics", diags.append, 10)
    fut = cell.call_async(cell.triggers["compute"])
    compute_pool = cell.node.calibration_mode.handoff.pools["compute"]
    assert cell.spin(lambda: compute_pool._work_queue.qsize() == 0 and not fut.done(), 5.0)
    before = cell.node.diag.counter("left_images")
    n_diag = len(diags)
    q = cell.world.arm.joint_names and np.zeros(len(cell.world.arm.joint_names))
    blank = np.zeros((360, 640, 3), np.uint8)
    for _ in range(3):
        cell.show(q, 0, images=(blank, blank))
        cell.spin(lambda: False, 0.4)
    during = cell.node.diag.counter("left_images") - before
    assert not fut.done(), "compute finished too early to show anything"
    assert during == 3
    assert len(diags) > n_diag                        # diagnostics kept being published
    assert cell.spin(fut.done, 120.0)
    assert fut.result().success, fut.result().message


def test_eye_to_hand_live(tmp_path, ros_context, executor, namespace, spin_until):
    """setup: eye_to_hand: a fixed camera, the board on the flange. The same relative views
    as the eye-in-hand world (the images are the world's renders), the robot reporting the
    flange pose that holds the board there; X = base_T_cam."""
    from eye_in_hand.core.transforms import from_rotvec, transform_distance
    from eye_in_hand.io.config import load_hand_eye
    from eye_in_hand.sim.scenarios import calibration_poses

    c = _Cell(tmp_path, ros_context, executor, namespace, spin_until, setup="eye_to_hand",
              capture_timeout_s=3.0)
    base_T_cam = from_rotvec([2.3, 0.2, -0.3], [0.9, -0.2, 0.7])        # the fixed camera
    ee_T_board = from_rotvec([0.1, np.pi - 0.1, 0.2], [0.01, 0.02, 0.1])
    w = c.world

    def flange(q):   # holds the board where the camera sees it as the world's camera at q does
        cam_T_board = np.linalg.inv(w.base_T_cam(q)) @ w.base_T_board
        return base_T_cam @ cam_T_board @ np.linalg.inv(ee_T_board)

    for k, q in enumerate(calibration_poses(w, 7, seed=2)):
        fut = c.call_async(c.triggers["capture"])
        c.spin(lambda: bool(c.node.calibration_mode._waiters), 5.0)
        stamp = max(c.node.get_clock().now().nanoseconds, c.clock_ns + 400 * MS)
        c.clock_ns = stamp
        T = flange(q)
        for dt in range(-300, 301, 25):
            c.pub_pose.publish(matrix_to_pose_stamped(T, stamp_ns=stamp + dt * MS,
                                                      frame_id="base_link"))
        left, right = c.render(q, k)
        c.pub_l.publish(numpy_to_image(left, "bgr8", stamp_ns=stamp))
        c.pub_r.publish(numpy_to_image(right, "bgr8", stamp_ns=stamp))
        assert c.spin(fut.done, 30.0)
        assert fut.result().success, fut.result().message
    res = c.trigger("compute")
    assert res.success, res.message
    X = c.node.calibration_mode.session.result.X
    dt, dr = transform_distance(X, base_T_cam)
    assert dt < 1e-3 and np.degrees(dr) < 0.1, (dt, np.degrees(dr))
    assert c.trigger("save").success
    saved = load_hand_eye(c.out / "hand_eye.yaml")
    assert saved.setup == "eye_to_hand" and saved.parent_frame == "base_link"
