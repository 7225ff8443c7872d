"""The ``hand_eye`` node's parameters: :class:`HandEyeNodeConfig` (docs/localization.md,
docs/handeye.md).

A part of :class:`eye_in_hand.nodes.hand_eye.HandEyeNode`: every parameter with its
description and range, validated once at start-up into this frozen config
(:func:`eye_in_hand.ros.params.load_config`); the calibration mode's capture and status rules
are those of :class:`eye_in_hand.core.handeye.session.SessionConfig`, whose defaults they take.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from eye_in_hand.core.defaults import POSE_RULES
from eye_in_hand.core.handeye.calibrate import ROBOT_MODELS
from eye_in_hand.core.handeye.plan import PlanConfig
from eye_in_hand.core.handeye.session import SessionConfig
from eye_in_hand.errors import ConfigError, InputError
from eye_in_hand.ros.outputs import MARKER_LIFETIME_S, RIGHT_CAMERA_FRAME, TARGET_FRAME_PREFIX
from eye_in_hand.ros.params import param, params_of

__all__ = ["HandEyeNodeConfig", "parameter_names"]

#: The calibration session's rules: their defaults are the calibration-mode parameters'.
_SESSION = SessionConfig()


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

    def session_config(self) -> SessionConfig:
        """The calibration session's rules: the parameters of :class:`SessionConfig`'s names.

        Raises:
            ConfigError: a rule the session refuses.
        """
        try:
            return SessionConfig(**{f.name: getattr(self, f.name)
                                    for f in dataclasses.fields(SessionConfig)})
        except InputError as exc:
            raise ConfigError(str(exc)) from exc

    def plan_config(self) -> PlanConfig | None:
        """The next poses' plan (``suggest_count`` of them, the robot sigmas); None: none."""
        if self.suggest_count == 0:
            return None
        return PlanConfig(count=self.suggest_count, robot_sigma_pos_m=self.robot_sigma_pos_m,
                          robot_sigma_rot_rad=self.robot_sigma_rot_rad)


def parameter_names(values: Mapping[str, Any]) -> list[str]:
    """Every parameter name the node declares (``values``: its parameters in a file, unused)."""
    return [p.name for p in params_of(HandEyeNodeConfig)]
