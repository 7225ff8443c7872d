"""The ``hand_eye`` node's TF input and output (docs/localization.md).

:class:`TfInput` and :class:`TfOutput` are parts of
:class:`eye_in_hand.nodes.hand_eye.HandEyeNode`, built with explicit arguments:
``robot_pose_source: tf`` feeds ``/tf`` and ``/tf_static`` into a
:class:`eye_in_hand.core.tf.TfBuffer` whose ``base_frame -> ee_frame`` chain replaces the
localizer's pose buffer; with ``publish_tf`` (and tf2_msgs installed) it publishes
``/tf_static`` (``ee_frame -> camera_frame``, or ``base_frame -> camera_frame`` eye-to-hand, and
``camera_frame -> right_camera_frame``) and ``/tf`` ``base_frame -> target_frame``.
"""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from eye_in_hand.core.camera import StereoRig
from eye_in_hand.core.tf import TfBuffer, TfPoseView
from eye_in_hand.errors import ConfigError, EyeInHandError
from eye_in_hand.ros import tf as ros_tf  # have_tf2_msgs, tf_message_class looked up per call
from eye_in_hand.ros.outputs import rclpy_types, tf_message
from eye_in_hand.ros.outputs_cdr import translation_tf_cdr
from eye_in_hand.ros.qos import ROBOT_POSE_DEPTH
from eye_in_hand.ros.tf import (
    TF_STATIC_TOPIC,
    TF_TOPIC,
    feed_tf_message,
    tf_qos,
    tf_static_pub_qos,
    tf_static_sub_qos,
)

__all__ = ["TfInput", "TfOutput"]


class TfInput:
    """Robot poses from /tf + /tf_static (``robot_pose_source: tf``): a TF buffer whose
    ``base_frame -> ee_frame`` chain replaces the localizer's pose buffer (same interpolation,
    gap and no-extrapolation rules, looked up at each image stamp).

    Args:
        node: the rclpy node that owns the subscriptions and the log.
        config: the node's configuration (``pose_buffer_size``, ``base_frame``, ``ee_frame``,
            ``pose_jump_back_s``).
        localizer: the :class:`~eye_in_hand.core.localization.Localizer` whose ``poses`` this
            replaces.
        diag: the node's diagnostics (counters ``tf_messages``, ``tf_rejected``,
            ``pose_buffer_resets.time_jump``; cause ``bad_tf``).
        now_ns: the node's clock (receive times of the transforms).
        after_pose: called when the chain reached a newer stamp (a new robot pose).

    Raises:
        ConfigError: tf2_msgs is not available.
    """

    def __init__(self, node: Any, config: Any, localizer: Any, diag: Any,
                 now_ns: Callable[[], int], after_pose: Callable[[], None]) -> None:
        try:
            TFMessage = ros_tf.tf_message_class()
        except ConfigError as exc:
            raise ConfigError(f"robot_pose_source: tf: {exc}") from exc
        self._log = node.get_logger()
        self._diag = diag
        self._now_ns = now_ns
        self._after_pose = after_pose
        self.buffer = TfBuffer(config.pose_buffer_size)
        self.poses = TfPoseView(self.buffer, config.base_frame, config.ee_frame,
                                jump_back_ns=int(config.pose_jump_back_s * 1e9))
        localizer.poses = self.poses
        # as deep as the robot pose topics' queue: a burst of late /tf while the executor is
        # busy (a capture, a slow machine) is kept, not dropped as a gap in the robot's motion
        node.create_subscription(TFMessage, TF_TOPIC, lambda m: self.on_tf(m, False),
                                 tf_qos(ROBOT_POSE_DEPTH))
        node.create_subscription(TFMessage, TF_STATIC_TOPIC, lambda m: self.on_tf(m, True),
                                 tf_static_sub_qos())
        diag.declare_counter("tf_messages", "tf_rejected")

    def on_tf(self, msg: Any, static: bool) -> None:
        """Feed one TFMessage into the buffer; bad transforms are counted and reported."""
        self._diag.count("tf_messages")
        before = self.poses.newest_ns
        added, problems, jumped = feed_tf_message(self.poses, msg, static=static,
                                                  received_ns=self._now_ns())
        if jumped:
            self._diag.count("pose_buffer_resets.time_jump")
            self._log.info("TF time jumped back: dynamic transforms cleared, earlier ones are "
                           "never used again")
        for text in problems:
            self._diag.count("tf_rejected")
            self._diag.report("bad_tf", f"{'/tf_static' if static else '/tf'}: {text}")
        if added and self.poses.newest_ns != before:
            self._after_pose()   # the chain reached a newer stamp: a robot pose


class TfOutput:
    """Publishers of /tf_static (hand-eye, stereo extrinsic) and /tf (targets), when
    ``publish_tf`` is on and tf2_msgs is available (else one log line says why not).

    Args:
        node: the rclpy node (its log and clock).
        config: the node's configuration (``publish_tf``, frames, ``stereo_calibration_dir``,
            ``calibration_dir``, ``mode``).
        create: the node's output publisher factory
            (:meth:`eye_in_hand.ros.publishers.OutputPublishers.create`).
        camera_parent: the camera's parent frame (``ee_frame``, or ``base_frame`` eye-to-hand).

    Raises:
        ConfigError: ``stereo_calibration_dir`` cannot be read.
    """

    def __init__(self, node: Any, config: Any, create: Callable[..., Any],
                 camera_parent: str) -> None:
        self._node = node
        self._config = config
        self._camera_parent = camera_parent
        self.pub_tf: Any = None
        self.pub_tf_static: Any = None
        self._static_tf: dict[str, tuple[str, np.ndarray]] = {}
        cfg = config
        if not cfg.publish_tf:
            return
        if not ros_tf.have_tf2_msgs():
            node.get_logger().warning("tf2_msgs is not installed: no /tf or /tf_static "
                                      "published (run 'make venv' to build it)")
            return
        TFMessage = ros_tf.tf_message_class()
        self.pub_tf = create(TFMessage, TF_TOPIC, tf_qos())
        self.pub_tf_static = create(TFMessage, TF_STATIC_TOPIC, tf_static_pub_qos())
        rig = None
        cdir = cfg.stereo_calibration_dir or (cfg.calibration_dir if cfg.mode == "calibration"
                                              else "")
        if cdir and (Path(cdir) / "left.yaml").exists():
            try:
                rig = StereoRig.load(cdir)
            except EyeInHandError as exc:
                raise ConfigError(f"stereo_calibration_dir: {exc}") from exc
        elif cfg.stereo_calibration_dir:
            raise ConfigError(f"stereo_calibration_dir: {cdir} has no left.yaml + right.yaml")
        if rig is not None:
            self._static_tf[cfg.right_camera_frame] = (cfg.camera_frame,
                                                       np.linalg.inv(rig.right_T_left))

    def publish_static(self, ee_T_cam: np.ndarray | None, stamp_ns: int | None = None
                       ) -> None:
        """(Re)publish every static transform of the node in one /tf_static message, stamped
        ``stamp_ns`` (localization: the first image stamp) or now on the node's clock."""
        if self.pub_tf_static is None:
            return
        if ee_T_cam is not None:
            self._static_tf[self._config.camera_frame] = (self._camera_parent,
                                                          np.asarray(ee_T_cam))
        if not self._static_tf:
            return
        stamp = self._node.get_clock().now().nanoseconds if stamp_ns is None else stamp_ns
        self.pub_tf_static.publish(tf_message(rclpy_types(), (
            (parent, child, stamp, T) for child, (parent, T) in self._static_tf.items())))

    def publish_target(self, stamp_ns: int, p: np.ndarray) -> None:
        """``base_frame -> target_frame`` on /tf at the image stamp (translation only), when
        ``target_frame`` names a second frame for the first target."""
        if self.pub_tf is None or not self._config.target_frame:
            return
        self.pub_tf.publish(translation_tf_cdr(
            [(self._config.base_frame, self._config.target_frame, stamp_ns, p)]))

    def publish_edges(self, edges: list[tuple[str, str, int, np.ndarray]]) -> None:
        """Translation-only transforms on /tf (the every-target frames), when publishing."""
        if edges and self.pub_tf is not None:
            self.pub_tf.publish(translation_tf_cdr(edges))
