"""The ``hand_eye`` node: target in the robot base frame, and hand-eye calibration on the robot.

Localization mode (``mode: localization``)
    Subscribes ``target/point`` (geometry_msgs/PointStamped, left optical frame, from
    ``detect_triangulate``) and the robot pose: ``ee_pose`` (geometry_msgs/PoseStamped,
    base_link -> tool0) or ``joint_states`` (sensor_msgs/JointState, through a DH YAML or URDF
    kinematics file). Loads ``hand_eye.yaml``. For every point it interpolates the robot pose at
    the point's (image) stamp and publishes ``target/pose`` (PoseStamped in the base frame, stamp
    = image stamp, orientation identity: the target is a point) and ``target/pose_cov``
    (PoseWithCovarianceStamped; position block propagated from the triangulation covariance,
    the hand-eye covariance and the robot pose noise; orientation variances set to 1e6 rad^2,
    i.e. unknown). A point whose stamp is newer than the newest robot pose waits up to
    ``max_pose_wait_s`` for it; the pose is never extrapolated and never taken across a gap
    over ``max_pose_gap_s``, so when robot poses stop arriving no ``target/pose`` is published
    and ``diagnostics`` says why. Never stale: the robot poses used for a point must also have
    been *received* within ``max_pose_age_s`` before the point arrived (on the node's clock:
    wall time, or ``/clock`` under ``use_sim_time``), and the pose buffer is cleared when
    robot pose stamps (or the clock) jump back more than ``pose_jump_back_s`` (a bag replayed
    again) or no pose arrived for ``max_pose_age_s`` (the stream stopped). Every point that
    gives no ``target/pose`` is counted on ``diagnostics`` by reason (``refused.<reason>``).
    These rules are :class:`eye_in_hand.core.pipeline.LocalizationPipeline`'s, the same as
    ``process``'s: the node feeds it and publishes what it emits. On the system clock the
    robot poses are taken when a point or frame needs them, not one wake-up each
    (docs/localization.md). ``hand_eye/transform`` (TransformStamped tool0 -> camera,
    transient local) is published once at start-up.

Every target (see docs/ros.md "Every target")
    ``target/point`` is the first target only. The node learns each frame's set of targets
    from ``targets/markers`` (visualization_msgs/MarkerArray from ``detect_triangulate``: one
    per processed image pair, one SPHERE per located target, ``ns`` = target id) and reads
    each target's point and covariance from ``targets/<id>/point_cov``; it subscribes to
    that topic when the id first appears in a frame and, every ``discovery_period_s``, for
    every ``targets/<id>/point_cov`` publisher it finds in the ROS graph (so the targets a
    detector announces at start-up lose no frame). The subscription is transient local
    (``TARGET_POINT_QOS``, as detect_triangulate publishes): made when a new id first
    appears, it still receives the points sent before it matched, so that frame is not lost.
    Per-target topics sit next to their list
    topic (``targets/markers``, ``target/poses``) and follow its remapping. A frame waits up
    to ``max_target_wait_s`` for its targets' points and, eye-in-hand, for the robot pose as
    above; then it publishes,
    per located target, ``target/<id>/pose`` (PoseStamped) and ``target/<id>/pose_cov``
    (PoseWithCovarianceStamped), ``/tf`` ``base_frame -> <target_frame_prefix><id>``, and per
    frame ``target/poses`` (PoseArray, base frame, image stamp, poses in the order of the
    spheres) and ``target/markers`` (MarkerArray: DELETEALL, then the spheres in the base
    frame). Every listed target that gives no pose is counted in ``targets_rejected`` and
    ``target_refused.<reason>``: ``target_points = target_poses_published + targets_rejected
    + targets_pending``.

Eye-to-hand (a ``hand_eye.yaml`` with ``setup: eye_to_hand``, ``base_T_cam``)
    The camera is fixed: points go into the base frame with the calibration alone, no robot
    pose is subscribed, buffered or waited for (``robot_pose_source`` and the pose age rules
    do not apply), and the covariance is the camera covariance rotated into the base frame
    plus the hand-eye covariance. The same topics are published; ``hand_eye/transform`` and
    ``/tf_static`` give ``base_frame -> camera_frame``.

TF (see docs/localization.md)
    ``robot_pose_source: tf``: the robot pose is ``base_frame -> ee_frame`` looked up at each
    image stamp in a TF buffer (:class:`eye_in_hand.core.tf.TfBuffer`) fed by ``/tf`` and
    ``/tf_static`` (chained, interpolated per edge, never extrapolated, no bracket over
    ``max_pose_gap_s``). With ``publish_tf`` (and tf2_msgs installed) the node publishes
    ``/tf_static`` (``ee_frame -> camera_frame``, and ``camera_frame -> right_camera_frame``
    from ``stereo_calibration_dir``) and, for every located target, ``/tf``
    (``base_frame -> target_frame`` at the image stamp).

Calibration mode (``mode: calibration``)
    Subscribes ``left/image_raw`` (and ``right/image_raw`` for a stereo rig) and the robot pose.
    Services (std_srvs/Trigger): ``hand_eye/capture`` takes the newest image, detects the board,
    pairs it with the robot pose interpolated at the image stamp, and refuses while the robot
    moves; ``hand_eye/compute`` solves AX = XB with every method and refines; ``hand_eye/save``
    writes ``hand_eye.yaml``, ``report.json`` and ``report.html`` to ``output_dir`` (the same files
    as ``eye-in-hand calibrate handeye``); ``hand_eye/reset`` forgets the samples.
    ``diagnostics`` shows the sample count and the motion diversity.
"""
from __future__ import annotations

import time
from collections import deque
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from eye_in_hand.core.pipeline import LocalizationPipeline, PipelineRules
from eye_in_hand.io.config import load_hand_eye
from eye_in_hand.io.kinematics import load_kinematics
from eye_in_hand.nodes.hand_eye_calibration import CalibrationMode
from eye_in_hand.nodes.hand_eye_first_target import FirstTarget
from eye_in_hand.nodes.hand_eye_params import HandEyeNodeConfig, parameter_names
from eye_in_hand.nodes.hand_eye_poses import RobotPoseInput, build_localizers
from eye_in_hand.nodes.hand_eye_targets import EveryTarget
from eye_in_hand.nodes.hand_eye_tf import TfOutput
from eye_in_hand.ros.diagnostics import NodeDiagnostics
from eye_in_hand.ros.executor import DueTimers
from eye_in_hand.ros.node_main import run_node
from eye_in_hand.ros.outputs import LocatedFrame
from eye_in_hand.ros.params import load_config
from eye_in_hand.ros.publishers import OutputPublishers

__all__ = ["HandEyeNode", "parameter_names", "main"]

NODE_NAME = "hand_eye"
#: period of the waits' check while a point or a frame waits, and of the idle check (s)
WAIT_CHECK_PERIOD_S, IDLE_CHECK_PERIOD_S = 0.02, 0.2
#: while points or frames come, how often the periodic work due soon runs with them (s)
HOUSEKEEPING_LOOK_S = 0.1


class HandEyeNode(Node):
    """See the module docstring. ``kwargs`` go to ``Node`` (context, namespace, overrides).

    Its parts, objects with explicit constructor arguments: the parameters
    (:mod:`~eye_in_hand.nodes.hand_eye_params`); the ROS-free
    :class:`~eye_in_hand.core.pipeline.LocalizationPipeline` (pose waiting, staleness,
    interpolation, the localizer), fed with the robot poses
    (:mod:`~eye_in_hand.nodes.hand_eye_poses`), the first target
    (:mod:`~eye_in_hand.nodes.hand_eye_first_target`) and every target
    (:mod:`~eye_in_hand.nodes.hand_eye_targets`), which publish what it emits; TF in and
    out (:mod:`~eye_in_hand.nodes.hand_eye_tf`); and calibration mode
    (:mod:`~eye_in_hand.nodes.hand_eye_calibration`). The node builds them, runs the
    pipeline's waits on a steady clock and takes frames handed over in memory.
    """

    def __init__(self, *, in_process: bool = False, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        #: fed by :meth:`deliver` (a detector in the same process, :mod:`.localize`) instead
        #: of the camera-frame topics: no subscription to them, no message to parse
        self.in_process = in_process
        self.config: HandEyeNodeConfig = load_config(self, HandEyeNodeConfig)
        cfg = self.config
        self.diag = NodeDiagnostics(self, hardware_id=NODE_NAME)
        # output publishers without per-publisher QoS-event handlers: the wait set of every
        # executor wake-up stays small; their subscribers' QoS is checked periodically instead
        self.outputs = OutputPublishers(self, self.diag.report)
        self.calibration_mode: CalibrationMode | None = None
        chain = None    # load_kinematics: a DHChain or a UrdfChain
        if cfg.robot_pose_source == "joint_states":
            chain = load_kinematics(cfg.kinematics_file, cfg.urdf_base_link, cfg.urdf_tip_link)
        self.calibration = self._load_calibration()
        localizing = cfg.mode == "localization"
        setup = self.calibration.setup if localizing else cfg.setup
        #: a fixed camera (base_T_cam): localization needs no robot pose; in calibration
        #: mode the flange holds the board
        self.eye_to_hand = setup == "eye_to_hand"
        self.localizer, fixed = build_localizers(cfg, self.calibration)
        # the one localization pipeline: robot poses (every source) in; points and frames of
        # targets wait there for their robot pose, on a steady clock (waits end also while
        # simulated time stands still); its sinks are the first and every target
        self.pipeline = LocalizationPipeline(
            fixed or self.localizer,
            PipelineRules(max_pose_wait_s=cfg.max_pose_wait_s,
                          max_target_wait_s=cfg.max_target_wait_s),
            wait_clock=time.monotonic, kinematics=chain,
            cov_expected=None if in_process else self._cov_expected)
        # the camera does not move with the robot: localization subscribes no robot pose
        pose_source = None if self.eye_to_hand and localizing else cfg.robot_pose_source
        self.robot_poses = RobotPoseInput(self, cfg, self.pipeline, self.localizer, self.diag,
                                          self._now_ns, self._after_pose, pose_source)
        if localizing and not self.get_parameter("use_sim_time").value \
                and self.robot_poses.take_when_needed(self._on_system_clock):
            # poses at 125 Hz - 1 kHz taken with the point or frame that needs them, not one
            # executor wake-up each (receive times are the middleware's, on the system clock)
            self.pipeline.pull_poses = self.robot_poses.poll
        camera_parent = cfg.base_frame if self.eye_to_hand else cfg.ee_frame
        self.tf_output = TfOutput(self, cfg, self.outputs.create, camera_parent)
        if localizing:
            self._setup_localization(camera_parent)   # /tf_static at the first image stamp
        else:
            self.tf_output.publish_static(None)     # the stereo extrinsic, now
            self.calibration_mode = CalibrationMode(
                self, cfg, self.diag, self.localizer.poses, self._now_ns,
                self.tf_output.publish_static)
        self.get_logger().info(
            f"{NODE_NAME} started in {cfg.mode} mode, " + (
                "eye-to-hand (fixed camera, no robot pose)" if self.eye_to_hand else
                f"robot pose from {cfg.robot_pose_source}"))

    def _load_calibration(self) -> Any:
        """``hand_eye.yaml`` in localization mode (None in calibration mode); an eye-to-hand
        calibration whose parent is not ``base_frame`` is warned about."""
        cfg = self.config
        if cfg.mode != "localization":
            return None
        calibration = load_hand_eye(cfg.hand_eye_file)
        if calibration.setup == "eye_to_hand" and calibration.parent_frame != cfg.base_frame:
            self.get_logger().warning(
                f"{cfg.hand_eye_file}: the eye-to-hand calibration is "
                f"{calibration.parent_frame} -> {calibration.child_frame}, but "
                f"targets are published in base_frame {cfg.base_frame!r}")
        return calibration

    def _now_ns(self) -> int:
        """The node's clock: sim time under use_sim_time, else CLOCK_REALTIME (as rclpy's)."""
        return time.time_ns() if self._on_system_clock() else self.get_clock().now().nanoseconds

    def _on_system_clock(self) -> bool:
        return not getattr(self.get_clock(), "ros_time_is_active", False)  # not /clock

    def _after_pose(self) -> None:
        """After each robot pose: answer the captures waiting for it, or drain the pipeline."""
        if self.calibration_mode is not None:
            self.calibration_mode.poll()
        else:
            self.pipeline.drain()

    def _cov_expected(self) -> bool:
        """Whether a point waits for its covariance: a detector publishes them."""
        return self.count_publishers("target/point_cov") > 0

    # -- localization -----------------------------------------------------------------------
    def _setup_localization(self, camera_parent: str) -> None:
        cfg = self.config
        if self.in_process:
            # frames handed over by a detector thread, taken on the executor's thread
            self._inbox: deque[LocatedFrame] = deque()
            self._inbox_gc = self.create_guard_condition(self._drain_inbox)
        self.first_target = FirstTarget(
            self, cfg, self.diag, self.outputs.create, self.pipeline, self._now_ns,
            self._arm_waits, self.tf_output, (self.calibration.transform, camera_parent),
            self.in_process)
        self.targets = EveryTarget(     # the first target's bytes built once for both
            self, cfg, self.diag, self.outputs.create, self.pipeline, self._now_ns,
            self.first_target.first_data, self._arm_waits, self.tf_output, self.in_process,
            self.first_target.point_pose)
        # Steady time: waiting points expire and stopped pose streams are noticed also while
        # simulated time (use_sim_time) stands still. The waits are checked at 50 Hz only
        # while a point or a frame waits (a node that keeps up would wake 50 times a second
        # for nothing, each wake-up costing as much as a message's); a stopped pose stream and
        # the queue gauges are checked every IDLE_CHECK_PERIOD_S.
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._wait_timer = self.create_timer(WAIT_CHECK_PERIOD_S, self._check_waits,
                                             clock=steady)
        self._wait_timer.cancel()
        self._idle_timer = self.create_timer(IDLE_CHECK_PERIOD_S, self._idle_check,
                                             clock=steady)
        # periodic work: with the points and frames while they come, else on its timers
        self._housekeeping = DueTimers((self._idle_timer, self.diag.timer, self.outputs.timer,
                                        self.targets.discovery_timer), HOUSEKEEPING_LOOK_S)

    def _arm_waits(self) -> None:
        """Run the waits' check while a point or a frame waits (called where they queue), and
        take the robot poses as they arrive meanwhile; the periodic work due soon runs here."""
        self._housekeeping.poke()
        if self.pipeline.waiting:
            self.robot_poses.wake_for_poses(True)
            if self._wait_timer.is_canceled():
                self._wait_timer.reset()

    def _check_waits(self) -> None:
        """The waits' check: emit what is ready or waited long enough; stop when none waits."""
        if not self.pipeline.tick():
            self._wait_timer.cancel()
            self.robot_poses.wake_for_poses(False)

    def _idle_check(self) -> None:
        """A stopped stream or a clock jump clears the pose buffer; the queue gauges."""
        self.robot_poses.expire()
        self.diag.gauge("pending", len(self.pipeline.points))
        self.diag.gauge("targets_pending", self.pipeline.targets_waiting)

    # -- in-process input (one process with the detector: nodes/localize.py) ---------------
    def expect_targets(self, ids: list[str]) -> None:
        """Make the ``target/<id>/pose(_cov)`` publishers of a detector's known target ids
        now (in one process with it, where no graph search finds them), so that their
        subscribers match before the first frame."""
        self.targets.expect(ids)

    def deliver(self, frame: LocatedFrame) -> None:
        """Hand over one located stereo pair from a detector in this process (any thread):
        the same inputs as ``target/point(_cov)``, ``targets/<id>/point_cov`` and
        ``targets/markers`` carry, taken on the executor's thread in arrival order."""
        self._inbox.append(frame)
        self._inbox_gc.trigger()

    def _drain_inbox(self) -> None:
        while self._inbox:
            self._take_frame_in_process(self._inbox.popleft())

    def _take_frame_in_process(self, f: LocatedFrame) -> None:
        """What the topic callbacks do with a pair's messages, in their order (first target,
        every target's point, the list of targets), from the detector's values."""
        if f.first is not None:
            self.first_target.take_located(f.stamp_ns, f.frame_id, f.first[0], f.first[1])
        for sphere, cov in f.targets:
            self.targets.take_point(sphere.id, f.stamp_ns, f.frame_id, sphere.xyz, cov)
        self.targets.take_markers(f.stamp_ns, f.frame_id, [s for s, _ in f.targets])

    def destroy_node(self) -> None:
        if self.calibration_mode is not None:
            self.calibration_mode.shutdown()
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    """Console entry point: ``ros2 run eye_in_hand hand_eye``."""
    run_node(NODE_NAME, HandEyeNode, args)


if __name__ == "__main__":
    main()
