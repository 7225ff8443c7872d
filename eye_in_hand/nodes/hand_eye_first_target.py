"""The ``hand_eye`` node's first target: ``target/point(_cov)`` in, ``target/pose(_cov)`` out.

:class:`FirstTarget` is a part of :class:`eye_in_hand.nodes.hand_eye.HandEyeNode` (an object
with explicit constructor arguments): it hands each first-target camera point (and its
covariance) to the node's :class:`~eye_in_hand.core.pipeline.LocalizationPipeline`, which
waits for the robot pose and puts it into the base frame, and publishes what the pipeline
emits for it: ``target/pose`` (PoseStamped), ``target/pose_cov`` (PoseWithCovarianceStamped)
and ``/tf`` ``base_frame -> target_frame``; at the first image stamp it latches
``hand_eye/transform`` and ``/tf_static``.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from geometry_msgs.msg import (
    PointStamped,
    PoseStamped,
    PoseWithCovarianceStamped,
    TransformStamped,
)

from eye_in_hand.core.pipeline import LocalizationPipeline, WaitingPoint
from eye_in_hand.errors import ConversionError, InputError
from eye_in_hand.io.cdr import (
    marker_array_from_cdr,
    point_stamped_from_cdr,
    pose_cov_stamped_from_cdr,
)
from eye_in_hand.nodes.hand_eye_poses import fields_decoder
from eye_in_hand.nodes.hand_eye_tf import TfOutput
from eye_in_hand.ros.decoded import decoded_subscription, undecodable
from eye_in_hand.ros.geometry import (
    point_stamped_fields,
    pose_cov_stamped_fields,
    position_covariance,
    xyz_values,
)
from eye_in_hand.ros.markers import marker_array_fields
from eye_in_hand.ros.outputs import rclpy_types, transform_stamped
from eye_in_hand.ros.outputs_cdr import LastPointPose
from eye_in_hand.ros.qos import LATCHED_QOS, RESULT_QOS
from eye_in_hand.ros.stamps import sec_nanosec_to_ns

__all__ = ["FirstTarget", "point_decoder", "point_cov_decoder", "markers_decoder"]

# the detector's messages as their fields (read from their bytes; ``fields_decoder``)
#: ``decoder_for`` of ``target/point``: its fields ``(sec, nanosec, frame_id, (x, y, z))``
point_decoder = fields_decoder(point_stamped_from_cdr, point_stamped_fields)
#: ``decoder_for`` of ``target/point_cov`` and ``targets/<id>/point_cov``: their fields
#: ``(sec, nanosec, frame_id, pose (7), covariance (36))``
point_cov_decoder = fields_decoder(pose_cov_stamped_from_cdr, pose_cov_stamped_fields)
#: ``decoder_for`` of ``targets/markers``: each marker's fields (``eye_in_hand.io.cdr.
#: MarkerFields``; read by the every-target part)
markers_decoder = fields_decoder(marker_array_from_cdr, marker_array_fields)


class FirstTarget:
    """The first target of the ``hand_eye`` node, and its latched hand-eye transform.

    Args:
        node: the rclpy node (the subscriptions).
        config: the node's configuration (``camera_frame``, ``base_frame``,
            ``stale_after_s``).
        diag: the node's diagnostics (counters ``points``, ``poses_published``,
            ``rejected``, ``refused.<reason>``; gauges ``latency_ms``, ``sigma_mm``).
        create: the node's output publisher factory (``OutputPublishers.create``).
        pipeline: the node's pipeline: this feeds it points and is its point sink.
        now_ns: the node's clock (receive times, latency).
        arm_waits: called when a point starts to wait for its robot pose.
        tf_output: the node's :class:`~eye_in_hand.nodes.hand_eye_tf.TfOutput`.
        camera_T: the hand-eye transform (``ee_T_cam``, or ``base_T_cam`` eye-to-hand) and
            the camera's parent frame, latched on ``hand_eye/transform``.
        in_process: fed by :meth:`take_located` from a detector in this process, not by the
            ``target/point(_cov)`` subscriptions.

    Its :attr:`point_pose` (the serializer of a located point) is the every-target part's
    too, which sends the first target again: its bytes are built once.
    """

    def __init__(self, node: Any, config: Any, diag: Any, create: Callable[..., Any],
                 pipeline: LocalizationPipeline, now_ns: Callable[[], int],
                 arm_waits: Callable[[], None], tf_output: TfOutput,
                 camera_T: tuple[np.ndarray, str], in_process: bool) -> None:
        self.config = config
        self.point_pose = LastPointPose()
        self.diag = diag
        self.pipeline = pipeline
        pipeline.point_sink = self
        self._now_ns = now_ns
        self._arm_waits = arm_waits
        self._tf_output = tf_output
        self._camera_T, self._camera_parent = camera_T
        if not in_process:
            decoded_subscription(node, PointStamped, "target/point", self._on_point,
                                 RESULT_QOS, decoder_for=point_decoder,
                                 on_bad=self._undecodable_point)
            decoded_subscription(node, PoseWithCovarianceStamped, "target/point_cov",
                                 self._on_point_cov, RESULT_QOS, decoder_for=point_cov_decoder,
                                 on_bad=lambda t, e: diag.report("bad_point_cov",
                                                                 undecodable(t, e)))
        self.pub_pose = create(PoseStamped, "target/pose", RESULT_QOS)
        self.pub_pose_cov = create(PoseWithCovarianceStamped, "target/pose_cov", RESULT_QOS)
        self.pub_transform = create(TransformStamped, "hand_eye/transform", LATCHED_QOS)
        self._data_stamp_ns: int | None = None   # the first image stamp this node received
        diag.declare_counter("points", "poses_published", "rejected", "refused.stale_pose",
                             "refused.pending_overflow", "pose_buffer_resets.time_jump",
                             "pose_buffer_resets.stream_stopped")
        diag.stale_after("points", config.stale_after_s)

    def first_data(self, stamp_ns: int) -> None:
        """At the first image stamp received (a point or a frame's list of targets): latch
        ``hand_eye/transform`` and ``/tf_static`` stamped with it, in data time as every other
        output (a bag's time on a replay), once."""
        if self._data_stamp_ns is not None:
            return
        self._data_stamp_ns = stamp_ns
        self.pub_transform.publish(transform_stamped(
            rclpy_types(), self._camera_T, stamp_ns, self._camera_parent,
            self.config.camera_frame))
        self._tf_output.publish_static(self._camera_T, stamp_ns)

    # -- camera-frame input -----------------------------------------------------------------
    def _camera_frame_ok(self, topic: str, frame: str) -> bool:
        """Whether ``frame`` is the camera frame (or empty); else the point is refused."""
        if frame and frame.lstrip("/") != self.config.camera_frame:
            self._refuse("point_frame", f"{topic} in frame {frame!r}, expected "
                         f"{self.config.camera_frame!r}: ignored")
            return False
        return True

    def take_located(self, stamp: int, frame: str, p: np.ndarray, cov: np.ndarray | None
                     ) -> None:
        """The first target of a pair located in this process: what ``target/point`` and
        ``target/point_cov`` carry, as their callbacks take it."""
        self.diag.count("points")
        self.first_data(stamp)
        if self._camera_frame_ok("target/point", frame):
            self._take_point(stamp, p, cov)

    def _on_point(self, fields: tuple[Any, ...]) -> None:
        """A ``target/point`` (its fields, :data:`point_decoder`)."""
        self.diag.count("points")
        sec, nanosec, frame, xyz = fields
        try:
            stamp = sec_nanosec_to_ns(sec, nanosec, "header.stamp")
            self.first_data(stamp)
            if not self._camera_frame_ok("target/point", frame):
                return
            p = xyz_values(xyz, "point")
        except (ConversionError, InputError) as exc:
            self._refuse("bad_point", f"target/point: {exc}")
            return
        self._take_point(stamp, p, None)    # its covariance, when that came first

    def _undecodable_point(self, topic: str, exc: Exception) -> None:
        """A ``target/point`` whose bytes do not decode: a point received and refused."""
        self.diag.count("points")
        self._refuse("bad_point", undecodable(topic, exc))

    def _take_point(self, stamp: int, p: np.ndarray, cov: np.ndarray | None) -> None:
        """Queue the first target's camera point (and covariance) in the pipeline until its
        robot pose is there."""
        self.pipeline.add_point(stamp, p, cov, received_ns=self._now_ns())
        self._arm_waits()

    def _on_point_cov(self, fields: tuple[Any, ...]) -> None:
        """Triangulation covariance for the point with the same stamp (position block; the
        fields of :data:`point_cov_decoder`)."""
        sec, nanosec, _frame, _pose, values = fields
        try:
            stamp = sec_nanosec_to_ns(sec, nanosec, "header.stamp")
            cov = position_covariance(values, "pose.covariance")
            if not np.isfinite(cov).all():
                raise InputError("covariance contains NaN")
        except (ConversionError, InputError) as exc:
            self.diag.report("bad_point_cov", f"target/point_cov: {exc}")
            return
        self.pipeline.add_point_cov(stamp, cov)

    def _refuse(self, reason: str, message: str, cause: str | None = None) -> None:
        """Count a point that gives no target/pose in ``rejected`` and ``refused.<reason>``;
        report (log once, WARN) under ``cause`` (default: the reason)."""
        self.diag.count("rejected")
        self.diag.count(f"refused.{reason}")
        self.diag.report(cause or reason, message)

    # -- what the pipeline emits (the first target) ---------------------------------------
    def point_located(self, item: WaitingPoint, p: np.ndarray, cov: np.ndarray) -> None:
        """A point in the base frame: ``target/pose(_cov)`` and ``/tf``."""
        stamp_ns = item.stamp_ns
        # volatile topics: a message nobody subscribes to reaches no one, now or later, so it
        # is neither built nor sent (counted all the same); /tf always goes out
        want = (self.pub_pose.get_subscription_count() > 0,
                self.pub_pose_cov.get_subscription_count() > 0)
        if any(want):
            # serialized directly (ros.outputs_cdr: the bytes of ros.outputs' messages)
            msg, cmsg = self.point_pose(p, cov, stamp_ns, self.config.base_frame)
            if want[0]:
                self.pub_pose.publish(msg)
            if want[1]:
                self.pub_pose_cov.publish(cmsg)
        self._tf_output.publish_target(stamp_ns, p)
        self.diag.count("poses_published")
        self.diag.gauge("latency_ms", round((self._now_ns() - stamp_ns) / 1e6, 3))
        trace = float(cov[0, 0] + cov[1, 1] + cov[2, 2])
        self.diag.gauge("sigma_mm", round(1000.0 * math.sqrt(max(trace, 0.0)), 4))

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
