"""hand_eye node, localization mode, in-process: pose at the image stamp, covariance, faults."""
from __future__ import annotations

import numpy as np
import pytest
import yaml
from rclpy.node import Node
from rclpy.parameter import Parameter

from eye_in_hand.core.kinematics import DHChain
from eye_in_hand.core.localization import target_in_base
from eye_in_hand.core.transforms import from_rotvec, interpolate
from eye_in_hand.errors import ConfigError
from eye_in_hand.io.config import HandEyeCalibration, save_hand_eye
from eye_in_hand.nodes.hand_eye import HandEyeNode
from eye_in_hand.ros.geometry import matrix_to_pose_stamped, xyz_to_point_stamped
from eye_in_hand.ros.qos import LATCHED_QOS, RESULT_QOS, SENSOR_QOS
from eye_in_hand.ros.stamps import header_stamp_ns, make_header

EE_T_CAM = from_rotvec([0.1, -0.2, 0.05], [0.03, -0.05, 0.08])
T0 = 1_700_000_000_000_000_000


def _hand_eye_file(tmp_path, cov=None):
    path = tmp_path / "hand_eye.yaml"
    save_hand_eye(path, HandEyeCalibration(
        setup="eye_in_hand", parent_frame="tool0", child_frame="camera_left_optical_frame",
        transform=EE_T_CAM, method="refined", covariance=cov, sample_count=15))
    return path


def _robot_pose(t_s: float) -> np.ndarray:
    return from_rotvec([0.0, 0.3 * np.sin(t_s), 0.2 * t_s], [0.4 + 0.1 * t_s, 0.1, 0.5])


class _Rig:
    """Publishers/subscribers around a HandEyeNode in the test's namespace."""

    def __init__(self, ros_context, executor, namespace, overrides, robot="ee_pose"):
        from geometry_msgs.msg import (
            PointStamped,
            PoseStamped,
            PoseWithCovarianceStamped,
            TransformStamped,
        )
        from sensor_msgs.msg import JointState

        self.node = HandEyeNode(context=ros_context, namespace=namespace,
                                parameter_overrides=overrides)
        self.io = Node("he_io", context=ros_context, namespace=namespace)
        executor.add_node(self.node)
        executor.add_node(self.io)
        self.pub_pose = self.io.create_publisher(PoseStamped, "ee_pose", SENSOR_QOS)
        self.pub_js = self.io.create_publisher(JointState, "joint_states", SENSOR_QOS)
        self.pub_point = self.io.create_publisher(PointStamped, "target/point", RESULT_QOS)
        self.pub_cov = self.io.create_publisher(PoseWithCovarianceStamped, "target/point_cov",
                                                RESULT_QOS)
        self.poses, self.covs, self.transforms, self.diags = [], [], [], []
        self.io.create_subscription(PoseStamped, "target/pose", self.poses.append, RESULT_QOS)
        self.io.create_subscription(PoseWithCovarianceStamped, "target/pose_cov",
                                    self.covs.append, RESULT_QOS)
        self.io.create_subscription(TransformStamped, "hand_eye/transform",
                                    self.transforms.append, LATCHED_QOS)
        from diagnostic_msgs.msg import DiagnosticArray
        self.io.create_subscription(DiagnosticArray, "diagnostics", self.diags.append, 10)

    def connected(self):
        return (self.pub_point.get_subscription_count() > 0
                and self.pub_pose.get_subscription_count()
                + self.pub_js.get_subscription_count() > 0
                and self.io.count_publishers("target/pose") > 0)

    def send_pose(self, t_s):
        self.pub_pose.publish(matrix_to_pose_stamped(
            _robot_pose(t_s), stamp_ns=T0 + int(t_s * 1e9), frame_id="base_link"))

    def send_point(self, t_s, p, cov=None):
        stamp = T0 + int(t_s * 1e9)
        if cov is not None:
            from geometry_msgs.msg import PoseWithCovarianceStamped
            m = PoseWithCovarianceStamped()
            m.header = make_header(stamp, "camera_left_optical_frame")
            m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.position.z = map(float, p)
            full = np.zeros((6, 6))
            full[:3, :3] = cov
            m.pose.covariance = [float(v) for v in full.ravel()]
            self.pub_cov.publish(m)
        self.pub_point.publish(xyz_to_point_stamped(p, stamp_ns=stamp,
                                                    frame_id="camera_left_optical_frame"))


def _overrides(path, **extra):
    base = {"hand_eye_file": str(path), "robot_sigma_pos_m": 0.0, "robot_sigma_rot_rad": 0.0}
    base.update(extra)
    return [Parameter(k, value=v) for k, v in base.items()]


def test_pose_at_image_stamp_with_covariance(tmp_path, ros_context, executor, namespace,
                                             spin_until):
    cov_x = np.diag([1e-6, 1e-6, 1e-6, 1e-5, 1e-5, 1e-5])
    rig = _Rig(ros_context, executor, namespace, _overrides(_hand_eye_file(tmp_path, cov_x)))
    assert spin_until(executor, rig.connected, 10.0)
    for k in range(11):                 # robot poses every 10 ms over [0, 0.1] s
        rig.send_pose(0.01 * k)
    p_cam = np.array([0.02, -0.01, 0.45])
    cov_cam = np.diag([1e-8, 1e-8, 4e-7])
    rig.send_point(0.055, p_cam, cov_cam)   # between two robot poses
    assert spin_until(executor, lambda: len(rig.poses) == 1 and len(rig.covs) == 1, 10.0)
    out = rig.poses[0]
    assert header_stamp_ns(out) == T0 + 55_000_000 and out.header.frame_id == "base_link"
    base_T_ee = interpolate(T0 + 55_000_000, T0 + 50_000_000, _robot_pose(0.05),
                            T0 + 60_000_000, _robot_pose(0.06))
    want, want_cov = target_in_base(base_T_ee, EE_T_CAM, p_cam, cov_cam=cov_cam,
                                    cov_hand_eye=cov_x)
    got = np.array([out.pose.position.x, out.pose.position.y, out.pose.position.z])
    assert np.allclose(got, want, atol=1e-12)
    got_cov = np.asarray(rig.covs[0].pose.covariance).reshape(6, 6)
    assert np.allclose(got_cov[:3, :3], want_cov, rtol=1e-9, atol=1e-18)
    # hand_eye/transform: latched once, stamped with the first image stamp (data time)
    assert spin_until(executor, lambda: len(rig.transforms) == 1, 5.0)
    assert rig.transforms[0].header.frame_id == "tool0"
    assert header_stamp_ns(rig.transforms[0]) == T0 + 55_000_000


def test_the_periodic_work_runs_with_the_points_while_they_come(tmp_path, ros_context,
                                                               executor, namespace, spin_until):
    """While points come (20 Hz here), the node's periodic work (the idle check: a stopped pose
    stream, the queue gauges; diagnostics; the outputs' QoS check; the targets' graph search)
    runs with them when it falls due, its timers put back, so no timer wakes the node; once
    the points stop, the timers run it again."""
    import sys
    import time

    from eye_in_hand.nodes.hand_eye import HOUSEKEEPING_LOOK_S, IDLE_CHECK_PERIOD_S

    rig = _Rig(ros_context, executor, namespace, _overrides(_hand_eye_file(tmp_path)))
    assert spin_until(executor, rig.connected, 10.0)
    node = rig.node
    timers = {"idle": node._idle_timer, "diagnostics": node.diag.timer,
              "qos": node.outputs.timer, "discovery": node.targets.discovery_timer}
    runs: dict[str, list[tuple[float, bool]]] = {name: [] for name in timers}

    def watch(name, timer):
        callback = timer.callback

        def run():
            frame, inline = sys._getframe(1), False
            while frame is not None and not inline:
                inline, frame = frame.f_code.co_name == "_arm_waits", frame.f_back
            runs[name].append((time.monotonic(), inline))
            return callback()
        timer.callback = run

    for name, timer in timers.items():
        watch(name, timer)
    t0 = time.monotonic()
    k = 0
    while time.monotonic() - t0 < 2.5:
        rig.send_pose(0.05 * k)
        rig.send_pose(0.05 * k + 0.03)
        rig.send_point(0.05 * k + 0.01, [0.0, 0.0, 0.5])
        k += 1
        spin_until(executor, lambda: False, 0.05)
    streaming = time.monotonic() - t0
    idle = [t for t, inline in runs["idle"] if inline]
    # with the points: every HOUSEKEEPING_LOOK_S to IDLE_CHECK_PERIOD_S, never a longer gap
    assert len(idle) >= 0.6 * streaming / IDLE_CHECK_PERIOD_S, (len(idle), streaming)
    assert max(np.diff([t0, *idle])) < IDLE_CHECK_PERIOD_S + HOUSEKEEPING_LOOK_S, idle
    for name in ("diagnostics", "discovery", "qos"):
        assert any(inline for _, inline in runs[name]), (name, runs[name])
    # no timer woke the node on its own (one at most, a stall of the test's loop)
    on_their_own = [(name, t) for name, r in runs.items() for t, inline in r if not inline]
    assert len(on_their_own) <= 1, on_their_own
    assert rig.diags, "diagnostics still published"
    assert spin_until(executor, lambda: len(rig.poses) == k, 5.0), (len(rig.poses), k)
    for r in runs.values():
        r.clear()
    spin_until(executor, lambda: False, 5 * IDLE_CHECK_PERIOD_S + 0.1)
    assert not any(inline for r in runs.values() for _, inline in r)
    assert len(runs["idle"]) >= 3, runs["idle"]          # no point: the timers run it
    assert node.diag.snapshot().gauges["pending"] == 0


def test_a_busy_executor_does_not_refuse_points_whose_poses_wait_in_its_queue(
        tmp_path, ros_context, executor, namespace, spin_until):
    """The robot poses a point waits for arrive while the node's executor is busy elsewhere for
    longer than max_pose_wait_s: when it runs again, its periodic check must not refuse the
    point before the queued poses are delivered."""
    import time

    rig = _Rig(ros_context, executor, namespace,
               _overrides(_hand_eye_file(tmp_path), max_pose_wait_s=0.1))
    assert spin_until(executor, rig.connected, 10.0)
    for k in range(3):
        rig.send_pose(0.01 * k)
    rig.send_point(0.05, [0.0, 0.0, 0.5])            # newer than every pose: it waits
    assert spin_until(executor, lambda: len(rig.node.pipeline.points) == 1, 10.0)
    for k in range(3, 8):                            # the poses come ...
        rig.send_pose(0.01 * k)
    time.sleep(0.4)                                  # ... while the executor is busy
    assert spin_until(executor, lambda: len(rig.poses) == 1, 5.0)
    assert rig.node.diag.causes.get("no_robot_pose", 0) == 0


def test_robot_poses_are_taken_when_a_point_needs_them(tmp_path, ros_context, executor,
                                                        namespace, spin_until):
    """On the system clock the ee_pose subscription is passive: the poses wait in the
    middleware until a point needs them. A point newer than every pose makes the node take
    each pose as it arrives until the point is out; then the subscription is passive again."""
    from eye_in_hand.ros.executor import is_passive

    rig = _Rig(ros_context, executor, namespace, _overrides(_hand_eye_file(tmp_path)))
    assert spin_until(executor, rig.connected, 10.0)
    node = rig.node
    sub = node.robot_poses._sub
    assert node.robot_poses.lazy and node.pipeline.pull_poses is not None and is_passive(sub)
    for k in range(3):
        rig.send_pose(0.01 * k)
    p, cov = np.array([0.01, -0.02, 0.5]), np.diag([1e-8, 1e-8, 4e-7])
    rig.send_point(0.015, p, cov)                     # its poses come with it
    assert spin_until(executor, lambda: len(rig.poses) == 1, 10.0)
    rig.send_point(0.05, p, cov)                      # newer than every pose: it waits ...
    assert spin_until(executor, lambda: len(node.pipeline.points) == 1, 10.0)
    assert not is_passive(sub)                        # ... and the node wakes for each pose
    rig.send_pose(0.03)
    rig.send_pose(0.06)
    assert spin_until(executor, lambda: len(rig.poses) == 2, 5.0)
    assert spin_until(executor, lambda: is_passive(sub), 5.0)
    for got, (t, t0, t1) in zip(rig.poses, ((0.015, 0.01, 0.02), (0.05, 0.03, 0.06)),
                                strict=True):
        ns = [T0 + round(v * 1e9) for v in (t, t0, t1)]
        base_T_ee = interpolate(ns[0], ns[1], _robot_pose(t0), ns[2], _robot_pose(t1))
        want, _ = target_in_base(base_T_ee, EE_T_CAM, p)
        pos = got.pose.position
        assert header_stamp_ns(got) == ns[0]
        assert np.allclose([pos.x, pos.y, pos.z], want, atol=1e-12)
    assert node.diag.counter("robot_poses") == 5


def test_poses_are_left_to_the_executor_while_the_subscription_is_active(
        tmp_path, ros_context, executor, namespace, spin_until):
    """While a point waits the pose subscription is active, and the executor delivers its poses
    in order with the other topics: a pull then (a point or frame queued from the same batch)
    must not take newer poses ahead of older ones the executor has taken but not delivered."""
    import time

    rig = _Rig(ros_context, executor, namespace, _overrides(_hand_eye_file(tmp_path)))
    assert spin_until(executor, rig.connected, 10.0)
    node = rig.node
    node.robot_poses.wake_for_poses(True)
    for k in range(3):
        rig.send_pose(0.01 * k)
    time.sleep(0.3)                                   # queued in the middleware, not spun
    node.robot_poses.poll()
    assert node.diag.counter("robot_poses") == 0      # left for the executor's delivery
    assert spin_until(executor, lambda: node.diag.counter("robot_poses") == 3, 5.0)


def test_reception_times_of_zero_or_from_the_future_are_the_take_time(
        tmp_path, ros_context, executor, namespace, spin_until, monkeypatch):
    """A middleware that leaves received_timestamp 0 (or stamps ahead of the clock): the poses
    get the time they are taken, not an age that would refuse every point as stale."""
    import eye_in_hand.nodes.hand_eye_poses as poses_module

    real = poses_module.take_queued
    shifts = iter([0, 10**18])

    def bad_stamps(sub):
        taken = real(sub)
        return [(m, 0 if k % 2 == 0 else t + next(shifts, 10**18)) for k, (m, t) in
                enumerate(taken)]

    monkeypatch.setattr(poses_module, "take_queued", bad_stamps)
    rig = _Rig(ros_context, executor, namespace, _overrides(_hand_eye_file(tmp_path)))
    assert spin_until(executor, rig.connected, 10.0)
    for k in range(3):
        rig.send_pose(0.01 * k)
    rig.send_point(0.015, [0.0, 0.0, 0.5], np.diag([1e-8, 1e-8, 4e-7]))
    assert spin_until(executor, lambda: len(rig.poses) == 1, 10.0)
    assert rig.node.diag.counter("refused.stale_pose") == 0


def test_a_middleware_without_reception_times_takes_every_pose_on_arrival(
        tmp_path, ros_context, executor, namespace, spin_until, monkeypatch):
    import eye_in_hand.nodes.hand_eye_poses as poses_module

    monkeypatch.setattr(poses_module, "reception_times_known", lambda: False)
    rig = _Rig(ros_context, executor, namespace, _overrides(_hand_eye_file(tmp_path)))
    assert spin_until(executor, rig.connected, 10.0)
    assert not rig.node.robot_poses.lazy and rig.node.pipeline.pull_poses is None


def test_use_sim_time_switched_on_ends_taking_poses_when_needed(tmp_path, ros_context,
                                                                executor, namespace,
                                                                spin_until):
    """Receive ages move to /clock with use_sim_time: the poses then get the node's clock, not
    the middleware's reception time, and every later pose is taken on arrival."""
    from rosgraph_msgs.msg import Clock

    from eye_in_hand.ros.executor import is_passive

    rig = _Rig(ros_context, executor, namespace, _overrides(_hand_eye_file(tmp_path)))
    assert spin_until(executor, rig.connected, 10.0)
    node = rig.node
    assert node.robot_poses.lazy
    clock_pub = rig.io.create_publisher(Clock, "/clock", 10)
    node.set_parameters([Parameter("use_sim_time", value=True)])
    msg = Clock()
    msg.clock.sec = 100
    assert spin_until(executor, lambda: (clock_pub.publish(msg), False)[1]
                      or node.get_clock().now().nanoseconds == 100 * 10**9, 10.0)
    for k in range(3):
        rig.send_pose(0.01 * k)
    assert spin_until(executor, lambda: node.diag.counter("robot_poses") == 3, 10.0)
    assert not node.robot_poses.lazy and not is_passive(node.robot_poses._sub)
    # received at 100 s on /clock: a point arriving at 100 s finds them fresh
    rig.send_point(0.015, [0.0, 0.0, 0.5], np.diag([1e-8, 1e-8, 4e-7]))
    assert spin_until(executor, lambda: len(rig.poses) == 1, 10.0)


def test_stale_robot_pose_publishes_nothing_then_resumes(tmp_path, ros_context, executor,
                                                         namespace, spin_until):
    rig = _Rig(ros_context, executor, namespace,
               _overrides(_hand_eye_file(tmp_path), max_pose_wait_s=0.05))
    assert spin_until(executor, rig.connected, 10.0)
    for k in range(5):
        rig.send_pose(0.01 * k)
    rig.send_point(0.02, [0.0, 0.0, 0.5])
    assert spin_until(executor, lambda: len(rig.poses) == 1, 10.0)
    # Robot poses stop: points newer than the last pose must not produce a pose.
    for k in range(3):
        rig.send_point(0.1 + 0.03 * k, [0.0, 0.0, 0.5])
    assert spin_until(executor, lambda: rig.node.diag.causes.get("no_robot_pose", 0) >= 3, 10.0)
    assert len(rig.poses) == 1
    assert spin_until(executor, lambda: any(
        "no_robot_pose" in "".join(f"{v.key}{v.value}" for s in d.status for v in s.values)
        or "robot" in " ".join(s.message for s in d.status) for d in rig.diags), 5.0)
    # Poses return: output resumes.
    for k in range(30, 41):
        rig.send_pose(0.01 * k)
    rig.send_point(0.35, [0.0, 0.0, 0.5])
    assert spin_until(executor, lambda: len(rig.poses) == 2, 10.0)
    assert header_stamp_ns(rig.poses[1]) == T0 + 350_000_000


def test_joint_states_with_dh_kinematics(tmp_path, ros_context, executor, namespace, spin_until):
    from sensor_msgs.msg import JointState

    chain = DHChain.ur5e()
    kin = tmp_path / "arm.yaml"
    kin.write_text(yaml.safe_dump({"arm": chain.to_dict()}))
    rig = _Rig(ros_context, executor, namespace, _overrides(
        _hand_eye_file(tmp_path), robot_pose_source="joint_states", kinematics_file=str(kin)))
    assert spin_until(executor, rig.connected, 10.0)
    q = np.array([0.1, -1.2, 1.3, -1.6, -1.5, 0.2])
    names = list(chain.joint_names)
    for k in range(3):
        m = JointState()
        m.header = make_header(T0 + k * 10_000_000)
        m.name = names[::-1]                      # order differs from the chain's: mapped by name
        m.position = [float(v) for v in q[::-1]]
        rig.pub_js.publish(m)
    rig.send_point(0.01, [0.0, 0.0, 0.5])
    assert spin_until(executor, lambda: len(rig.poses) == 1, 10.0)
    want, _ = target_in_base(chain.fk(q), EE_T_CAM, [0.0, 0.0, 0.5])
    p = rig.poses[0].pose.position
    assert np.allclose([p.x, p.y, p.z], want, atol=1e-12)


def test_bad_points_are_counted_and_node_keeps_running(tmp_path, ros_context, executor,
                                                       namespace, spin_until):
    rig = _Rig(ros_context, executor, namespace, _overrides(_hand_eye_file(tmp_path)))
    assert spin_until(executor, rig.connected, 10.0)
    for k in range(5):
        rig.send_pose(0.01 * k)
    from geometry_msgs.msg import PointStamped
    nan_point = PointStamped()
    nan_point.header = make_header(T0 + 10_000_000, "camera_left_optical_frame")
    nan_point.point.x, nan_point.point.z = float("nan"), 0.5
    rig.pub_point.publish(nan_point)
    wrong = PointStamped()
    wrong.header = make_header(T0 + 20_000_000, "some_other_frame")
    wrong.point.z = 0.5
    rig.pub_point.publish(wrong)
    # bytes that do not decode (the node takes serialized messages and decodes them itself):
    # reported under the topic's cause, nothing else lost
    rig.pub_point.publish(b"\x00\x01\x00\x00\x07")
    rig.pub_cov.publish(b"\x00\x01\x00\x00\x07\x00")
    rig.pub_pose.publish(b"\x00\x01\x00\x00")
    # robot poses that decode but are refused: a NaN position, another frame
    nan_pose = matrix_to_pose_stamped(_robot_pose(0.045), stamp_ns=T0 + 45_000_000,
                                      frame_id="base_link")
    nan_pose.pose.position.y = float("nan")
    rig.pub_pose.publish(nan_pose)
    rig.pub_pose.publish(matrix_to_pose_stamped(_robot_pose(0.046), stamp_ns=T0 + 46_000_000,
                                                frame_id="tool0"))
    rig.send_point(0.03, [0.0, 0.0, 0.5])
    assert spin_until(executor, lambda: len(rig.poses) == 1, 10.0)
    causes = rig.node.diag.causes
    assert causes.get("bad_point") == 2 and causes.get("point_frame") == 1
    assert causes.get("bad_point_cov") == 1
    d = rig.node.diag      # the ledger: every point received is published, refused or waits
    assert d.counter("points") == 4
    assert d.counter("points") == d.counter("poses_published") + d.counter("rejected") + len(
        rig.node.pipeline.points)
    assert spin_until(executor, lambda: rig.node.diag.causes.get("bad_ee_pose") == 2
                      and rig.node.diag.causes.get("ee_pose_frame") == 1, 5.0)


@pytest.mark.parametrize("content, message", [
    (None, "not found"),
    ("setup: eye_in_hand\nparent_frame: tool0\nchild_frame: cam\ntranslation: [0, 0]\n"
     "quat_xyzw: [0, 0, 0, 1]\n", "translation"),
    ("setup: eye_in_hand\n", "missing"),
    ("setup: eye_in_hand\nparent_frame: tool0\nchild_frame: cam\ntranslation: [0, 0, .nan]\n"
     "quat_xyzw: [0, 0, 0, 1]\n", "translation"),
])
def test_missing_or_malformed_hand_eye_file_refuses_to_start(tmp_path, ros_context, namespace,
                                                             content, message):
    path = tmp_path / "hand_eye.yaml"
    if content is not None:
        path.write_text(content)
    with pytest.raises(ConfigError, match=message) as info:
        HandEyeNode(context=ros_context, namespace=namespace,
                    parameter_overrides=[Parameter("hand_eye_file", value=str(path))])
    assert "hand_eye.yaml" in str(info.value)


def test_images_replayed_without_robot_poses_give_no_pose(tmp_path, ros_context, executor,
                                                          namespace, spin_until):
    """Issue #14: replay a bag once with ee_pose, then only its images: no target/pose may come
    out of the poses buffered during the first replay; every refusal is counted."""
    rig = _Rig(ros_context, executor, namespace,
               _overrides(_hand_eye_file(tmp_path), max_pose_age_s=0.3, max_pose_wait_s=0.05))
    assert spin_until(executor, rig.connected, 10.0)
    n = 12
    for k in range(n + 2):                 # first replay: robot poses and images
        rig.send_pose(0.01 * k)
    for k in range(n):
        rig.send_point(0.01 * k + 0.005, [0.0, 0.0, 0.5])
    ok = spin_until(executor, lambda: len(rig.poses) == n, 10.0)
    diag = rig.node.diag
    assert ok, (len(rig.poses), diag.snapshot().counters, diag.causes)
    # The robot pose stream has stopped: the buffer is cleared once it is older than the limit.
    assert spin_until(executor, lambda: diag.counter("pose_buffer_resets.stream_stopped") == 1,
                      10.0)
    for k in range(n):                     # second replay: the same images, no robot poses
        rig.send_point(0.01 * k + 0.005, [0.0, 0.0, 0.5])
    assert spin_until(executor, lambda: diag.counter("rejected") == n, 10.0)
    refused = {k: v for k, v in diag.snapshot().counters.items()
               if k.startswith("refused.") and v}
    assert sum(refused.values()) == n, refused
    assert diag.counter("points") == diag.counter("poses_published") + diag.counter("rejected")
    spin_until(executor, lambda: False, 0.3)   # anything late would arrive now
    assert len(rig.poses) == n


def test_poses_received_long_ago_are_refused_as_stale(tmp_path, ros_context, executor,
                                                      namespace, spin_until):
    """Refusal by receive age, not by buffer reset: a long age limit for stream stops is not
    needed; the lookup itself checks the age of the bracketing poses."""
    rig = _Rig(ros_context, executor, namespace,
               _overrides(_hand_eye_file(tmp_path), max_pose_age_s=0.3, max_pose_wait_s=0.05))
    assert spin_until(executor, rig.connected, 10.0)
    node = rig.node
    for k in range(4):
        rig.send_pose(0.01 * k)
    assert spin_until(executor, lambda: node.diag.counter("robot_poses") == 4, 10.0)
    # Keep the buffer from expiring (as if poses kept arriving for other stamps) and age the
    # clock seen by the lookup: the poses that bracket the stamp are now 5 s old.
    node.robot_poses.expire = lambda: None
    real_now = node._now_ns
    node.first_target._now_ns = lambda: real_now() + 5_000_000_000   # the points' arrival
    rig.send_point(0.015, [0.0, 0.0, 0.5])
    assert spin_until(executor, lambda: node.diag.counter("refused.stale_pose") == 1, 10.0)
    assert rig.poses == []


def test_a_bag_replayed_again_resets_the_pose_buffer(tmp_path, ros_context, executor,
                                                     namespace, spin_until):
    rig = _Rig(ros_context, executor, namespace, _overrides(_hand_eye_file(tmp_path)))
    assert spin_until(executor, rig.connected, 10.0)
    for k in range(0, 150):                # 1.5 s of robot poses (every 10 ms)
        rig.send_pose(0.01 * k)
        if k % 50 == 49:
            spin_until(executor, lambda k=k: rig.node.diag.counter("robot_poses") == k + 1, 10.0)
    assert spin_until(executor, lambda: rig.node.diag.counter("robot_poses") == 150, 10.0)
    assert len(rig.node.localizer.poses) == 150
    for k in range(5):                     # the bag starts again
        rig.send_pose(0.01 * k)
    assert spin_until(executor, lambda: rig.node.diag.counter("robot_poses") == 155, 10.0)
    assert rig.node.diag.counter("pose_buffer_resets.time_jump") == 1
    assert len(rig.node.localizer.poses) == 5
    rig.send_point(0.02, [0.0, 0.0, 0.5])
    assert spin_until(executor, lambda: len(rig.poses) == 1, 10.0)


def test_receive_age_uses_the_simulated_clock(tmp_path, ros_context, executor, namespace,
                                              spin_until):
    """With use_sim_time the receive age is measured on /clock: 2 s of simulated time without
    robot poses make them stale, although hardly any wall time passed."""
    from rosgraph_msgs.msg import Clock

    rig = _Rig(ros_context, executor, namespace,
               _overrides(_hand_eye_file(tmp_path), max_pose_wait_s=0.05) +
               [Parameter("use_sim_time", value=True)])
    clock_pub = rig.io.create_publisher(Clock, "/clock", 10)
    node = rig.node

    def set_clock(t_s: float) -> bool:
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(int(t_s * 1e9), 10**9)
        return spin_until(executor, lambda: (clock_pub.publish(msg), False)[1]
                          or node.get_clock().now().nanoseconds == int(t_s * 1e9), 10.0)

    assert spin_until(executor, rig.connected, 10.0)
    assert not node.robot_poses.lazy      # receive times on /clock: every pose taken on arrival
    assert set_clock(100.0)
    for k in range(5):
        rig.send_pose(0.01 * k)
    assert spin_until(executor, lambda: node.diag.counter("robot_poses") == 5, 10.0)
    assert set_clock(100.5)                       # 0.5 s later on /clock: fresh
    rig.send_point(0.015, [0.0, 0.0, 0.5])
    assert spin_until(executor, lambda: len(rig.poses) == 1, 10.0)
    assert set_clock(102.5)                       # 2.5 s on /clock: the stream has stopped
    rig.send_point(0.025, [0.0, 0.0, 0.5])
    assert spin_until(executor, lambda: node.diag.counter("rejected") == 1, 10.0)
    assert node.diag.counter("pose_buffer_resets.stream_stopped") \
        + node.diag.counter("refused.stale_pose") >= 1
    assert len(rig.poses) == 1


def test_robot_pose_noise_from_hand_eye_file_raises_the_parameters(
        tmp_path, ros_context, executor, namespace, spin_until):
    """hand_eye.yaml's optional robot_pose_noise (written while calibrating) raises the robot
    pose noise propagated into target/pose_cov above the robot_sigma_* parameters (here 0)."""
    from dataclasses import replace

    from eye_in_hand.io.config import load_hand_eye

    path = _hand_eye_file(tmp_path)
    noise = {"translation_sigma_m": 0.002, "rotation_sigma_rad": 0.003}
    save_hand_eye(path, replace(load_hand_eye(path), robot_pose_noise=noise))
    rig = _Rig(ros_context, executor, namespace, _overrides(path))   # parameters say 0, 0
    assert spin_until(executor, rig.connected, 10.0)
    for k in range(11):
        rig.send_pose(0.01 * k)
    p_cam = np.array([0.02, -0.01, 0.45])
    rig.send_point(0.05, p_cam, np.diag([1e-8, 1e-8, 4e-7]))
    assert spin_until(executor, lambda: len(rig.covs) == 1, 10.0)
    _, want_cov = target_in_base(_robot_pose(0.05), EE_T_CAM, p_cam,
                                 cov_cam=np.diag([1e-8, 1e-8, 4e-7]), robot_sigma_pos_m=0.002,
                                 robot_sigma_rot_rad=0.003)
    got_cov = np.asarray(rig.covs[0].pose.covariance).reshape(6, 6)
    assert np.allclose(got_cov[:3, :3], want_cov, rtol=1e-9, atol=1e-18)


def test_robot_pose_correction_from_hand_eye_file_is_applied(
        tmp_path, ros_context, executor, namespace, spin_until):
    """hand_eye.yaml's robot_pose_correction (the systematic robot model's): target/pose is
    the corrected robot pose at the image stamp, then X, then the point."""
    from dataclasses import replace

    from eye_in_hand.core.pose_correction import RobotPoseCorrection
    from eye_in_hand.io.config import load_hand_eye

    corr = RobotPoseCorrection(np.diag([0.05, -0.03, 0.04]), np.full((3, 3), 0.01),
                               _robot_pose(0.0)[:3, :3])
    path = _hand_eye_file(tmp_path)
    save_hand_eye(path, replace(load_hand_eye(path), robot_pose_correction=corr))
    rig = _Rig(ros_context, executor, namespace, _overrides(path))
    assert spin_until(executor, rig.connected, 10.0)
    for k in range(11):
        rig.send_pose(0.1 * k)
    p_cam = np.array([0.02, -0.01, 0.45])
    rig.send_point(0.5, p_cam)
    assert spin_until(executor, lambda: len(rig.poses) == 1, 10.0)
    got = rig.poses[0].pose.position
    want, _ = target_in_base(corr.apply(_robot_pose(0.5)), EE_T_CAM, p_cam)
    plain, _ = target_in_base(_robot_pose(0.5), EE_T_CAM, p_cam)
    assert np.linalg.norm(want - plain) > 1e-3
    assert np.allclose([got.x, got.y, got.z], want, atol=1e-9)
