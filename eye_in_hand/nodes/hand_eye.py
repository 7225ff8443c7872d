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
    ``process``'s: the node feeds it and publishes what it emits. ``hand_eye/transform``
    (TransformStamped tool0 -> camera, transient local) is published once at start-up.

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
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from geometry_msgs.msg import (
    PointStamped,
    PoseStamped,
    PoseWithCovarianceStamped,
    TransformStamped,
)
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from sensor_msgs.msg import JointState

from eye_in_hand.core.defaults import POSE_RULES
from eye_in_hand.core.eye_to_hand import EyeToHandLocalizer
from eye_in_hand.core.handeye.calibrate import ROBOT_MODELS
from eye_in_hand.core.handeye.session import SessionConfig
from eye_in_hand.core.localization import Localizer, robot_pose_sigmas
from eye_in_hand.core.pipeline import (
    LocalizationPipeline,
    PipelineRules,
    WaitingPoint,
    localizer_config,
)
from eye_in_hand.errors import ConversionError, EyeInHandError, InputError
from eye_in_hand.io.config import load_hand_eye
from eye_in_hand.io.kinematics import load_kinematics
from eye_in_hand.nodes.hand_eye_calibration import CalibrationMode
from eye_in_hand.nodes.hand_eye_targets import EveryTarget
from eye_in_hand.nodes.hand_eye_tf import TfInput, TfOutput
from eye_in_hand.ros.diagnostics import NodeDiagnostics
from eye_in_hand.ros.geometry import point_to_xyz, pose_to_matrix
from eye_in_hand.ros.node_main import run_node
from eye_in_hand.ros.outputs import (
    MARKER_LIFETIME_S,
    RIGHT_CAMERA_FRAME,
    TARGET_FRAME_PREFIX,
    LocatedFrame,
    header,
    pose_stamped,
    pose_with_covariance,
    rclpy_types,
    transform_stamped,
)
from eye_in_hand.ros.params import load_config, param, params_of
from eye_in_hand.ros.publishers import OutputPublishers
from eye_in_hand.ros.qos import LATCHED_QOS, RESULT_QOS, ROBOT_POSE_QOS
from eye_in_hand.ros.stamps import header_stamp_ns

__all__ = ["HandEyeNodeConfig", "HandEyeNode", "load_kinematics", "parameter_names", "main"]

#: The calibration session's rules: their defaults are the calibration-mode parameters'.
_SESSION = SessionConfig()

NODE_NAME = "hand_eye"
#: period of the waits' check while a point or a frame waits, and of the idle check (s)
WAIT_CHECK_PERIOD_S, IDLE_CHECK_PERIOD_S = 0.02, 0.2


def _existing_file(value: str) -> str | None:
    return None if not value or Path(value).is_file() else f"file not found: {value}"


@dataclass(frozen=True)
class HandEyeNodeConfig:
    """Parameters of the ``hand_eye`` node (validated once at start-up)."""

    mode: str = param("localization", "localization: publish target/pose; calibration: "
                      "collect samples through the hand_eye/* services",
                      choices=("localization", "calibration"))
    hand_eye_file: str = param("", "hand_eye.yaml to load (required in localization mode)",
                               validate=_existing_file)
    robot_pose_source: str = param("ee_pose", "where the robot pose comes from: the ee_pose "
                                   "topic (PoseStamped), joint_states + kinematics_file, or "
                                   "tf (/tf + /tf_static, base_frame -> ee_frame)",
                                   choices=("ee_pose", "joint_states", "tf"))
    kinematics_file: str = param("", "DH YAML (the 'arm' mapping of world.yaml: d, a, alpha, "
                                 "...) or URDF file, for robot_pose_source joint_states",
                                 validate=_existing_file)
    urdf_base_link: str = param("base_link", "URDF chain root link (URDF kinematics only)")
    urdf_tip_link: str = param("tool0", "URDF chain tip link (URDF kinematics only)")
    base_frame: str = param("base_link", "robot base frame id (frame of target/pose)")
    ee_frame: str = param("tool0", "end-effector frame id (parent of the camera)")
    camera_frame: str = param("camera_left_optical_frame", "left optical frame id; points in "
                              "another non-empty frame are rejected")
    max_pose_gap_s: float = param(
        POSE_RULES.max_pose_gap_s, "largest gap between the two robot poses that bracket an "
        "image stamp (s)", range=(1e-4, 10.0))
    max_pose_wait_s: float = param(0.2, "how long a point waits for a robot pose newer than "
                                   "its stamp before it is dropped as stale (s)",
                                   range=(0.0, 10.0))
    max_pose_age_s: float = param(
        POSE_RULES.max_pose_age_s, "largest receive age of the robot poses used for a point, "
        "on the node's clock (sim time under use_sim_time); older poses are refused as stale "
        "(s)", range=(0.001, 3600.0))
    pose_jump_back_s: float = param(
        POSE_RULES.pose_jump_back_s, "a robot pose stamp (or the node's clock) this far behind "
        "the newest is a time jump (bag loop or replay, sim reset): the pose buffer is cleared "
        "(s)", range=(0.001, 3600.0))
    pose_buffer_size: int = param(4000, "robot poses kept for interpolation",
                                  range=(2, 1_000_000))
    robot_sigma_pos_m: float = param(
        POSE_RULES.robot_sigma_pos_m, "the arm's position accuracy per axis, 1 sigma (m); "
        "hand_eye.yaml's robot_pose_noise raises it when larger", range=(0.0, 1.0))
    robot_sigma_rot_rad: float = param(
        POSE_RULES.robot_sigma_rot_rad, "the arm's rotation accuracy about the flange per "
        "axis, 1 sigma (rad); hand_eye.yaml's robot_pose_noise raises it when larger",
        range=(0.0, 1.0))
    publish_tf: bool = param(True, "publish /tf_static (ee_frame -> camera_frame, camera_frame "
                             "-> right_camera_frame) at the first image stamp and /tf "
                             "(base_frame -> <target_frame_prefix><id> per located target); "
                             "needs tf2_msgs")
    right_camera_frame: str = param(RIGHT_CAMERA_FRAME, "right optical frame id "
                                    "(child of the stereo extrinsic on /tf_static)")
    stereo_calibration_dir: str = param("", "directory with left.yaml + right.yaml whose "
                                        "stereo extrinsic goes on /tf_static ('' = none; "
                                        "calibration mode uses calibration_dir)")
    target_frame: str = param("", "a second /tf child frame for the first target (the one of "
                              "target/pose), besides its target_<id>; '' = none, each target "
                              "has one name")
    target_frame_prefix: str = param(TARGET_FRAME_PREFIX, "every target's /tf child frame is "
                                     "this "
                                     "prefix + its id (base_frame -> target_<id>); empty = "
                                     "no per-target /tf")
    max_targets: int = param(64, "most target ids subscribed (targets/<id>/point_cov) and "
                             "published (target/<id>/pose); further ids are refused and "
                             "counted", range=(1, 10_000))
    max_target_wait_s: float = param(0.2, "how long a frame of targets/markers waits for its "
                                     "targets' targets/<id>/point_cov before the missing "
                                     "ones are refused (s)", range=(0.0, 10.0))
    discovery_period_s: float = param(1.0, "period of the ROS graph search for "
                                      "targets/<id>/point_cov publishers (s)",
                                      range=(0.05, 3600.0))
    marker_lifetime_s: float = param(MARKER_LIFETIME_S, "lifetime of the spheres on "
                                     "target/markers (s); 0 = until the next frame's DELETEALL",
                                     range=(0.0, 3600.0))
    stale_after_s: float = param(1.0, "diagnostics WARN when no robot pose or point arrived "
                                 "for this long (s)", range=(0.01, 3600.0))
    # -- calibration mode ---------------------------------------------------------------
    setup: str = param("eye_in_hand", "calibration mode: eye_in_hand (camera on the flange, "
                       "board fixed; X = ee_T_cam) or eye_to_hand (camera fixed, board on the "
                       "flange; X = base_T_cam). Localization mode takes it from hand_eye.yaml",
                       choices=("eye_in_hand", "eye_to_hand"))
    board: str = param("chessboard:9x6:0.025", "calibration board spec (calibration mode)")
    calibration_dir: str = param("", "directory with left.yaml + right.yaml (stereo) or "
                                 "camera.yaml (mono) for calibration mode")
    output_dir: str = param("hand_eye_calibration", "where hand_eye/save writes its files")
    overwrite_output: bool = param(False, "hand_eye/save may replace an output_dir that this "
                                   "node did not write itself (it always replaces its own)")
    still_window_s: float = param(
        _SESSION.still_window_s, "capture: the robot must be still over +- this window "
        "around the image stamp (s)", range=(0.0, 5.0))
    still_max_speed_m_s: float = param(
        _SESSION.still_max_speed_m_s, "capture: largest tool speed counted as still (m/s)",
        range=(0.0, 10.0))
    still_max_rot_speed_rad_s: float = param(
        _SESSION.still_max_rot_speed_rad_s, "capture: largest tool angular speed counted as "
        "still (rad/s)", range=(0.0, 10.0))
    capture_timeout_s: float = param(
        _SESSION.capture_timeout_s, "capture: how long a request waits for a new image pair "
        "and the robot poses covering its stillness window (s)", range=(0.05, 60.0))
    duplicate_translation_m: float = param(
        _SESSION.duplicate_translation_m, "capture: a robot pose within this distance (and "
        "duplicate_rotation_rad) of a sample's is the same pose, refused (m)",
        range=(0.0, 1.0))
    duplicate_rotation_rad: float = param(
        _SESSION.duplicate_rotation_rad, "capture: see duplicate_translation_m (rad)",
        range=(0.0, 3.15))
    min_samples: int = param(
        _SESSION.min_samples, "status: samples needed before the set can be good enough",
        range=(3, 1000))
    min_rotation_deg: float = param(
        _SESSION.min_rotation_deg, "status: the largest rotation between two samples must "
        "reach this (deg)", range=(0.0, 180.0))
    min_axis_diversity: float = param(
        _SESSION.min_axis_diversity, "status: smallest normalised eigenvalue of the "
        "motion-axis scatter needed (0: one axis, 1/3: all directions)", range=(0.0, 0.34))
    target_std_mm: float = param(
        _SESSION.target_std_mm, "status: the set is good enough when the 1-sigma translation "
        "of X is at most this (mm)", range=(0.0, 1000.0))
    target_std_deg: float = param(
        _SESSION.target_std_deg, "status: ... and its 1-sigma rotation at most this (deg)",
        range=(0.0, 180.0))
    robot_model: str = param(
        _SESSION.robot_model, "hand_eye/compute: robot pose error model, per_pose or "
        "systematic (a pose-dependent error fitted with X; when selected, hand_eye.yaml "
        "carries the robot pose correction that localization applies)",
        choices=ROBOT_MODELS)
    suggest_count: int = param(3, "next poses suggested after each capture (0 = none)",
                               range=(0, 20))
    debug_image_rate_hz: float = param(2.0, "largest rate of ~/debug_image (only while "
                                       "subscribed; 0 = never)", range=(0.0, 60.0))

    def __post_init__(self) -> None:
        if self.mode == "localization" and not self.hand_eye_file:
            raise ValueError("hand_eye_file: required in localization mode")
        if self.robot_pose_source == "joint_states" and not self.kinematics_file:
            raise ValueError("kinematics_file: required when robot_pose_source is joint_states")
        if self.mode == "calibration" and not self.calibration_dir:
            raise ValueError("calibration_dir: required in calibration mode")


def parameter_names(values: Mapping[str, Any]) -> list[str]:
    """Every parameter name the node declares (``values``: its parameters in a file, unused)."""
    return [p.name for p in params_of(HandEyeNodeConfig)]


class HandEyeNode(Node):
    """See the module docstring. ``kwargs`` go to ``Node`` (context, namespace, overrides).

    Its parts: the ROS-free :class:`~eye_in_hand.core.pipeline.LocalizationPipeline` (pose
    waiting, staleness, interpolation, the localizer), fed with the robot poses and the first
    target here, its output for that target published here (:meth:`point_located`,
    :meth:`point_refused`); every target (:mod:`~eye_in_hand.nodes.hand_eye_targets`, the
    pipeline's other feeder and sink), TF in and out (:mod:`~eye_in_hand.nodes.hand_eye_tf`)
    and calibration mode (:mod:`~eye_in_hand.nodes.hand_eye_calibration`) in their own
    modules.
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
        self._chain: Any = None    # load_kinematics: a DHChain or a UrdfChain
        if cfg.robot_pose_source == "joint_states":
            self._chain = load_kinematics(cfg.kinematics_file, cfg.urdf_base_link,
                                          cfg.urdf_tip_link)
        self.calibration = None
        self.eye_to_hand = False       # a fixed camera: base_T_cam, no robot pose needed
        ee_T_cam = np.eye(4)
        cov = None
        if cfg.mode == "localization":
            self.calibration = load_hand_eye(cfg.hand_eye_file)
            self.eye_to_hand = self.calibration.setup == "eye_to_hand"
            if self.eye_to_hand and self.calibration.parent_frame != cfg.base_frame:
                self.get_logger().warning(
                    f"{cfg.hand_eye_file}: the eye-to-hand calibration is "
                    f"{self.calibration.parent_frame} -> {self.calibration.child_frame}, but "
                    f"targets are published in base_frame {cfg.base_frame!r}")
            if not self.eye_to_hand:
                ee_T_cam, cov = self.calibration.transform, self.calibration.covariance
        # robot pose noise: the arm's stated accuracy (robot_sigma_* parameters), raised to
        # hand_eye.yaml's robot_pose_noise (estimated while calibrating) where that is larger
        sig_pos, sig_rot = robot_pose_sigmas(
            cfg.robot_sigma_pos_m, cfg.robot_sigma_rot_rad,
            None if self.calibration is None else self.calibration.robot_pose_noise)
        self.localizer = Localizer(ee_T_cam, cov, localizer_config(
            max_pose_gap_s=cfg.max_pose_gap_s, max_pose_age_s=cfg.max_pose_age_s,
            pose_jump_back_s=cfg.pose_jump_back_s, buffer_size=cfg.pose_buffer_size,
            robot_sigma_pos_m=sig_pos, robot_sigma_rot_rad=sig_rot),
            pose_correction=(None if self.calibration is None or self.eye_to_hand
                             else self.calibration.robot_pose_correction))
        # eye-to-hand: base_T_cam and its covariance, the same code as `process`
        self.fixed_localizer: EyeToHandLocalizer | None = None
        if self.eye_to_hand:
            assert self.calibration is not None
            self.fixed_localizer = EyeToHandLocalizer(self.calibration.transform,
                                                      self.calibration.covariance)

        # the one localization pipeline: robot poses (every source) in; points and frames of
        # targets wait there for their robot pose, on a steady clock (waits end also while
        # simulated time stands still); its sinks are set in _setup_localization
        self.pipeline = LocalizationPipeline(
            self.fixed_localizer or self.localizer,
            PipelineRules(max_pose_wait_s=cfg.max_pose_wait_s,
                          max_target_wait_s=cfg.max_target_wait_s),
            wait_clock=time.monotonic, kinematics=self._chain,
            cov_expected=None if in_process else self._cov_expected)

        if cfg.mode == "calibration":
            self.eye_to_hand = cfg.setup == "eye_to_hand"   # the flange holds the board
        if self.eye_to_hand and cfg.mode == "localization":
            pass   # the camera does not move with the robot: no robot pose is needed
        elif cfg.robot_pose_source == "ee_pose":
            self.create_subscription(PoseStamped, "ee_pose", self._on_ee_pose, ROBOT_POSE_QOS)
        elif cfg.robot_pose_source == "tf":
            self.tf_input = TfInput(self, cfg, self.localizer, self.diag, self._now_ns,
                                    self._after_tf_pose)
        else:
            self.create_subscription(JointState, "joint_states", self._on_joint_state,
                                     ROBOT_POSE_QOS)
        self.diag.declare_counter("robot_poses")
        if not self.eye_to_hand or cfg.mode == "calibration":
            self.diag.stale_after("robot_poses", cfg.stale_after_s)

        self.tf_output = TfOutput(self, cfg, self.outputs.create, self._camera_parent)
        if cfg.mode == "localization":
            self._setup_localization()      # /tf_static at the first image stamp (first_data)
        else:
            self.tf_output.publish_static(None)     # the stereo extrinsic, now
            self.calibration_mode = CalibrationMode(self, self.tf_output.publish_static)
        self.get_logger().info(
            f"{NODE_NAME} started in {cfg.mode} mode, " + (
                "eye-to-hand (fixed camera, no robot pose)" if self.eye_to_hand else
                f"robot pose from {cfg.robot_pose_source}"))

    # -- robot pose -----------------------------------------------------------------------
    def _on_ee_pose(self, msg: PoseStamped) -> None:
        try:
            stamp = header_stamp_ns(msg)
            frame = msg.header.frame_id
            if frame and frame.lstrip("/") != self.config.base_frame:
                self.diag.report("ee_pose_frame", f"ee_pose in frame {frame!r}, expected "
                                 f"{self.config.base_frame!r}: ignored")
                return
            self._pose_added(stamp, self.pipeline.add_pose(stamp, pose_to_matrix(msg.pose),
                                                           received_ns=self._now_ns()))
        except (ConversionError, InputError) as exc:
            self.diag.report("bad_ee_pose", f"ee_pose: {exc}")
            return
        self._after_pose()

    def _on_joint_state(self, msg: JointState) -> None:
        try:
            stamp = header_stamp_ns(msg)
            self._pose_added(stamp, self.pipeline.add_joint_state(
                stamp, msg.name, msg.position, received_ns=self._now_ns()))
        except (ConversionError, InputError, EyeInHandError) as exc:
            self.diag.report("bad_joint_states", f"joint_states: {exc}")
            return
        self._after_pose()

    # -- staleness: receive times, time jumps, stopped streams ------------------------------
    def _now_ns(self) -> int:
        """The node's clock (sim time under use_sim_time): the clock of receive ages."""
        return self.get_clock().now().nanoseconds

    def _pose_added(self, stamp: int, jumped: bool) -> None:
        """A robot pose went into the pipeline (with its receive time); ``jumped``: a time
        jump back cleared the pose buffer first."""
        if jumped:
            self.diag.count("pose_buffer_resets.time_jump")
            self.get_logger().info(f"robot pose time jumped back (stamp {stamp} ns): pose "
                                   "buffer cleared, earlier poses are never used again")

    def _expire_poses(self) -> None:
        """Clear the pose buffer when the stream stopped or the clock jumped back."""
        cause = self.localizer.poses.expire(self._now_ns(),
                                            int(self.config.max_pose_age_s * 1e9))
        if cause is not None:
            self.diag.count(f"pose_buffer_resets.{cause}")
            self.get_logger().info(f"robot pose buffer cleared ({cause.replace('_', ' ')})")

    def _refuse(self, reason: str, message: str, cause: str | None = None) -> None:
        """Count a point that gives no target/pose in ``rejected`` and ``refused.<reason>``;
        report (log once, WARN) under ``cause`` (default: the reason)."""
        self.diag.count("rejected")
        self.diag.count(f"refused.{reason}")
        self.diag.report(cause or reason, message)

    def _after_tf_pose(self) -> None:
        self.pipeline.pose_arrived()     # the TF view in the localizer reached a newer stamp
        self._after_pose()

    def _after_pose(self) -> None:
        self.diag.count("robot_poses")
        if self.calibration_mode is not None:
            self.calibration_mode.poll()
        else:
            self.pipeline.drain()

    # -- localization -----------------------------------------------------------------------
    def _setup_localization(self) -> None:
        cfg = self.config
        self.pipeline.point_sink = self
        if self.in_process:
            # frames handed over by a detector thread, taken on the executor's thread
            self._inbox: deque[LocatedFrame] = deque()
            self._inbox_gc = self.create_guard_condition(self._drain_inbox)
        else:
            self.create_subscription(PointStamped, "target/point", self._on_point, RESULT_QOS)
            self.create_subscription(PoseWithCovarianceStamped, "target/point_cov",
                                     self._on_point_cov, RESULT_QOS)
        self.pub_pose = self.outputs.create(PoseStamped, "target/pose", RESULT_QOS)
        self.pub_pose_cov = self.outputs.create(PoseWithCovarianceStamped, "target/pose_cov",
                                                  RESULT_QOS)
        self.pub_transform = self.outputs.create(TransformStamped, "hand_eye/transform",
                                                   LATCHED_QOS)
        self._data_stamp_ns: int | None = None   # the first image stamp this node received
        self.diag.declare_counter("points", "poses_published", "rejected", "refused.stale_pose",
                                  "refused.pending_overflow", "pose_buffer_resets.time_jump",
                                  "pose_buffer_resets.stream_stopped")
        self.diag.stale_after("points", cfg.stale_after_s)
        self.targets = EveryTarget(
            self, cfg, self.diag, self.outputs.create, self.pipeline, self._now_ns,
            self._pose_messages, self.first_data, self._arm_waits, self.tf_output,
            self.in_process)
        # Steady time: waiting points expire and stopped pose streams are noticed also while
        # simulated time (use_sim_time) stands still. The waits are checked at 50 Hz only
        # while a point or a frame waits (a node that keeps up would wake 50 times a second
        # for nothing, each wake-up costing as much as a message's); a stopped pose stream and
        # the queue gauges are checked at 5 Hz.
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._wait_timer = self.create_timer(WAIT_CHECK_PERIOD_S, self._check_waits,
                                             clock=steady)
        self._wait_timer.cancel()
        self.create_timer(IDLE_CHECK_PERIOD_S, self._idle_check, clock=steady)

    def first_data(self, stamp_ns: int) -> None:
        """At the first image stamp received (a point or a frame's list of targets): latch
        ``hand_eye/transform`` and ``/tf_static`` stamped with it, in data time as every other
        output (a bag's time on a replay), once."""
        if self._data_stamp_ns is not None:
            return
        self._data_stamp_ns = stamp_ns
        assert self.calibration is not None
        self.pub_transform.publish(transform_stamped(
            rclpy_types(), self.calibration.transform, stamp_ns, self._camera_parent,
            self.config.camera_frame))
        self.tf_output.publish_static(self.calibration.transform, stamp_ns)

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
            self.diag.count("points")
            self.first_data(f.stamp_ns)
            if self._camera_frame_ok("target/point", f.frame_id):
                self._take_point(f.stamp_ns, f.first[0], f.first[1])
        for sphere, cov in f.targets:
            self.targets.take_point(sphere.id, f.stamp_ns, f.frame_id, sphere.xyz, cov)
        self.targets.take_markers(f.stamp_ns, f.frame_id, [s for s, _ in f.targets])

    # -- camera-frame topics ----------------------------------------------------------------
    def _camera_frame_ok(self, topic: str, frame: str) -> bool:
        """Whether ``frame`` is the camera frame (or empty); else the point is refused."""
        if frame and frame.lstrip("/") != self.config.camera_frame:
            self._refuse("point_frame", f"{topic} in frame {frame!r}, expected "
                         f"{self.config.camera_frame!r}: ignored")
            return False
        return True

    def _on_point(self, msg: PointStamped) -> None:
        self.diag.count("points")
        try:
            stamp = header_stamp_ns(msg)
            self.first_data(stamp)
            if not self._camera_frame_ok("target/point", msg.header.frame_id):
                return
            p = point_to_xyz(msg.point)
        except (ConversionError, InputError) as exc:
            self._refuse("bad_point", f"target/point: {exc}")
            return
        self._take_point(stamp, p, None)    # its covariance, when that came first

    def _take_point(self, stamp: int, p: np.ndarray, cov: np.ndarray | None) -> None:
        """Queue the first target's camera point (and covariance) in the pipeline until its
        robot pose is there."""
        self.pipeline.add_point(stamp, p, cov, received_ns=self._now_ns())
        self._arm_waits()

    def _on_point_cov(self, msg: PoseWithCovarianceStamped) -> None:
        """Triangulation covariance for the point with the same stamp (position block)."""
        try:
            stamp = header_stamp_ns(msg)
            cov = np.asarray(msg.pose.covariance, dtype=np.float64).reshape(6, 6)[:3, :3]
            if not np.all(np.isfinite(cov)):
                raise InputError("covariance contains NaN")
        except (ConversionError, InputError, ValueError) as exc:
            self.diag.report("bad_point_cov", f"target/point_cov: {exc}")
            return
        self.pipeline.add_point_cov(stamp, cov)

    def _cov_expected(self) -> bool:
        """Whether a point waits for its covariance: a detector publishes them."""
        return self.count_publishers("target/point_cov") > 0

    def _arm_waits(self) -> None:
        """Run the waits' check while a point or a frame waits (called where they queue)."""
        if self.pipeline.waiting and self._wait_timer.is_canceled():
            self._wait_timer.reset()

    def _check_waits(self) -> None:
        """The waits' check: emit what is ready or waited long enough; stop when none waits."""
        if not self.pipeline.tick():
            self._wait_timer.cancel()

    def _idle_check(self) -> None:
        self._expire_poses()
        self.diag.gauge("pending", len(self.pipeline.points))
        self.diag.gauge("targets_pending", self.pipeline.targets_waiting)

    @property
    def _camera_parent(self) -> str:
        """The parent frame of the camera: base_frame (eye-to-hand) or ee_frame."""
        return self.config.base_frame if self.eye_to_hand else self.config.ee_frame

    # -- what the pipeline emits (the first target) ---------------------------------------
    def point_located(self, item: WaitingPoint, p: np.ndarray, cov: np.ndarray) -> None:
        """A point in the base frame: ``target/pose(_cov)`` and ``/tf``."""
        self._publish(item.stamp_ns, p, cov)

    def point_refused(self, item: WaitingPoint, reason: str, detail: str) -> None:
        """A point that gives no ``target/pose``: counted and reported by reason."""
        if reason == "pending_overflow":
            self._refuse(reason, f"more than {self.pipeline.rules.max_waiting_points} points "
                         f"wait for robot poses: the oldest (at {item.stamp_ns} ns) was dropped")
        elif reason == "bad_point_cov":
            self._refuse(reason, f"target/point_cov at {item.stamp_ns} ns: {detail}")
        else:
            self._refuse(reason, f"no target/pose for the point at {item.stamp_ns} ns: "
                         f"{detail}", cause="no_robot_pose")

    def _pose_messages(self, stamp_ns: int, p: np.ndarray, cov: np.ndarray
                       ) -> tuple[PoseStamped, PoseWithCovarianceStamped]:
        """PoseStamped and PoseWithCovarianceStamped of a base-frame point (3,) and its
        covariance (3, 3); orientation identity, orientation variances unknown
        (:mod:`eye_in_hand.ros.outputs`, as ``process`` writes them)."""
        if not np.all(np.isfinite(p)):
            raise ConversionError(f"base-frame point is not finite: {p}")
        T = rclpy_types()
        hdr = header(T, stamp_ns, self.config.base_frame)
        return (pose_stamped(T, p, stamp_ns, "", hdr),
                pose_with_covariance(T, p, cov, stamp_ns, "", hdr))

    def _publish(self, stamp_ns: int, p: np.ndarray, cov: np.ndarray) -> None:
        # volatile topics: a message nobody subscribes to reaches no one, now or later, so it
        # is neither built nor sent (counted all the same); /tf always goes out
        want = (self.pub_pose.get_subscription_count() > 0,
                self.pub_pose_cov.get_subscription_count() > 0)
        if any(want):
            msg, cmsg = self._pose_messages(stamp_ns, p, cov)
            if want[0]:
                self.pub_pose.publish(msg)
            if want[1]:
                self.pub_pose_cov.publish(cmsg)
        self.tf_output.publish_target(stamp_ns, p)
        self.diag.count("poses_published")
        self.diag.gauge("latency_ms", round((self.get_clock().now().nanoseconds - stamp_ns) / 1e6,
                                            3))
        self.diag.gauge("sigma_mm", round(1000.0 * float(np.sqrt(max(np.trace(cov), 0.0))), 4))

    def destroy_node(self) -> None:
        if self.calibration_mode is not None:
            self.calibration_mode.shutdown()
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    """Console entry point: ``ros2 run eye_in_hand hand_eye``."""
    run_node(NODE_NAME, HandEyeNode, args)


if __name__ == "__main__":
    main()
