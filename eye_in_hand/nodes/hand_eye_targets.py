"""The ``hand_eye`` node's every-target outputs (docs/ros.md "Every target").

:class:`EveryTarget` is a part of :class:`eye_in_hand.nodes.hand_eye.HandEyeNode` (an object with
explicit constructor arguments): it reads
each frame's list of targets from ``targets/markers`` and every target's point from
``targets/<id>/point_cov``, hands them to the node's
:class:`~eye_in_hand.core.pipeline.LocalizationPipeline` (which waits for the points and the
robot pose, and puts each into the base frame) and publishes what it emits:
``target/<id>/pose(_cov)``, ``/tf`` ``base_frame -> <target_frame_prefix><id>``,
``target/poses`` and ``target/markers``.
"""
from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from rclpy.clock import Clock, ClockType
from rclpy.qos import DurabilityPolicy

from eye_in_hand.core.pipeline import LocalizationPipeline, WaitingFrame
from eye_in_hand.errors import ConversionError
from eye_in_hand.nodes.hand_eye_first_target import markers_decoder, point_cov_decoder
from eye_in_hand.ros.decoded import decoded_subscription, undecodable
from eye_in_hand.ros.geometry import position_covariance, xyz_values
from eye_in_hand.ros.markers import (
    Sphere,
    marker_classes,
    pose_array_class,
    spheres_from_marker_fields,
)
from eye_in_hand.ros.names import topic_name_problem
from eye_in_hand.ros.outputs_cdr import LastPointPose, pose_array_cdr, sphere_markers_cdr
from eye_in_hand.ros.qos import RESULT_QOS, TARGET_POINT_QOS
from eye_in_hand.ros.stamps import sec_nanosec_to_ns

__all__ = ["EveryTarget"]


class EveryTarget:
    """Every-target part of the ``hand_eye`` node: frames of ``targets/markers``, the points of
    ``targets/<id>/point_cov``, their outputs.

    Args:
        node: the rclpy node (subscriptions, timers, the ROS graph, topic name resolution).
        config: the node's configuration (frames, ``max_targets``, ``max_target_wait_s``,
            ``discovery_period_s``, ``marker_lifetime_s``, ``target_frame_prefix``).
        diag: the node's diagnostics.
        create: the node's output publisher factory (``OutputPublishers.create``).
        pipeline: the node's :class:`~eye_in_hand.core.pipeline.LocalizationPipeline`: this
            feeds it frames and target points and is its frame sink.
        now_ns: the node's clock (the receive-age clock of the robot poses).
        first_data: called with each frame's stamp (the node latches its transforms once).
        arm_waits: called when a frame starts to wait.
        tf_output: the node's :class:`~eye_in_hand.nodes.hand_eye_tf.TfOutput`.
        in_process: fed by :meth:`take_point` and :meth:`take_markers` from a detector in this
            process, not by subscriptions and graph discovery.
        point_pose: the node's serializer of a located point (shared with the first-target
            part: the first target's bytes are built once).
    """

    def __init__(self, node: Any, config: Any, diag: Any, create: Callable[..., Any],
                 pipeline: LocalizationPipeline, now_ns: Callable[[], int],
                 first_data: Callable[[int], None], arm_waits: Callable[[], None],
                 tf_output: Any, in_process: bool, point_pose: LastPointPose) -> None:
        """``targets/markers`` in (the frame's list of targets), ``targets/<id>/point_cov`` in
        per id, ``target/<id>/pose(_cov)``, ``target/poses`` and ``target/markers`` out."""
        self._node = node
        self.config = cfg = config
        self.diag = diag
        self._create = create
        self.pipeline = pipeline
        pipeline.frame_sink = self
        self._now_ns = now_ns
        self._first_data = first_data
        self._arm_waits = arm_waits
        self._tf_output = tf_output
        self.in_process = in_process
        self._point_pose = point_pose
        _, MarkerArray = marker_classes()
        # the frame being emitted: its located targets and their /tf edges (reused lists)
        self._located: list[tuple[Sphere, np.ndarray]] = []
        self._tf_edges: list[tuple[str, str, int, np.ndarray]] = []
        self.subs: dict[str, Any] = {}
        self._target_pubs: dict[str, tuple[Any, Any]] = {}
        # per-target topics follow their list topic's remapping: targets/<id>/point_cov next to
        # targets/markers, target/<id>/pose(_cov) next to target/poses
        self._targets_prefix = node.resolve_topic_name("targets/markers").rsplit("/", 1)[0]
        self._poses_prefix = node.resolve_topic_name("target/poses").rsplit("/", 1)[0]
        if not in_process:
            decoded_subscription(node, MarkerArray, "targets/markers", self._on_markers,
                                 RESULT_QOS, decoder_for=markers_decoder,
                                 on_bad=lambda name, exc: self._bad_markers(
                                     undecodable(name, exc)))
        self.pub_poses = create(pose_array_class(), "target/poses", RESULT_QOS)
        self.pub_markers = create(MarkerArray, "target/markers", RESULT_QOS)
        diag.declare_counter("target_frames", "target_points", "target_points_received",
                             "target_poses_published", "targets_rejected",
                             "target_frames_published", "orphan_target_points",
                             "target_refused.stale_pose", "target_refused.no_point")
        #: the graph search's timer (None in one process with the detector)
        self.discovery_timer: Any = None
        if not in_process:
            self.discovery_timer = node.create_timer(
                cfg.discovery_period_s, self._discover_targets,
                clock=Clock(clock_type=ClockType.STEADY_TIME))
            self._discover_targets()

    def _discover_targets(self) -> None:
        """Subscribe to every ``targets/<id>/point_cov`` that has a publisher in the graph."""
        prefix, suffix = self._targets_prefix + "/", "/point_cov"
        for name, _types in self._node.get_topic_names_and_types():
            if name.startswith(prefix) and name.endswith(suffix):
                tid = name[len(prefix):-len(suffix)]
                if tid and "/" not in tid and tid not in self.subs \
                        and self._node.count_publishers(name) > 0:
                    self._subscribe_target(tid)

    def expect(self, ids: list[str]) -> None:
        """Make the ``target/<id>/pose(_cov)`` publishers of a detector's known target ids
        now (in one process with it, where no graph search finds them), so that their
        subscribers match before the first frame."""
        for tid in ids:
            self._subscribe_target(tid)

    def _subscribe_target(self, tid: str) -> str | None:
        """Subscribe to ``targets/<tid>/point_cov`` and make the ``target/<tid>/pose(_cov)``
        publishers (once, so that their subscribers match before the first frame); the
        refusal reason when ``tid`` names no valid topic or ``max_targets`` ids are subscribed
        already, else None."""
        if tid in self.subs:
            return None
        problem = topic_name_problem(f"targets/{tid}/point_cov") if tid and "/" not in tid \
            else "empty or contains '/'"
        if problem is not None:
            return "bad_target_id"
        if len(self.subs) >= self.config.max_targets:
            return "too_many_targets"
        topic = f"{self._targets_prefix}/{tid}/point_cov"
        self.subs[tid] = None if self.in_process else decoded_subscription(
            self._node, PoseWithCovarianceStamped, topic,
            functools.partial(self._on_target_point, tid), self._target_point_qos(topic),
            decoder_for=point_cov_decoder,
            on_bad=lambda name, exc: self._bad_target_point(undecodable(name, exc)))
        base = f"{self._poses_prefix}/{tid}"
        self._target_pubs[tid] = (
            self._create(PoseStamped, f"{base}/pose", RESULT_QOS),
            self._create(PoseWithCovarianceStamped, f"{base}/pose_cov", RESULT_QOS))
        return None

    def _target_point_qos(self, topic: str) -> Any:
        """TARGET_POINT_QOS (transient local: the points published before this subscription
        matched still come, so a new id's first frame is not lost), or RESULT_QOS (volatile)
        when a publisher of ``topic`` known in the graph is volatile (a detector that does not
        keep its points: a transient-local subscription would not match it)."""
        infos = self._node.get_publishers_info_by_topic(topic)
        if any(i.qos_profile.durability != DurabilityPolicy.TRANSIENT_LOCAL for i in infos):
            return RESULT_QOS
        return TARGET_POINT_QOS

    def _on_target_point(self, tid: str, fields: tuple[Any, ...]) -> None:
        """A target's point and covariance (``targets/<id>/point_cov``; the fields of
        ``point_cov_decoder``), kept for its frame."""
        sec, nanosec, frame, pose, values = fields
        try:
            stamp = sec_nanosec_to_ns(sec, nanosec, "header.stamp")
            p = xyz_values(pose[:3], "pose.pose.position")
            cov = position_covariance(values, "pose.covariance")
        except ConversionError as exc:
            self._bad_target_point(f"targets/{tid}/point_cov: {exc}")
            return
        self.take_point(tid, stamp, frame, p, cov)
        self.pipeline.drain()

    def _bad_target_point(self, message: str) -> None:
        """A ``targets/<id>/point_cov`` message that gives no point: counted and reported
        (its frame then misses the point)."""
        self.diag.count("target_points_received")
        self.pipeline.target_point_arrived()
        self.diag.report("bad_target_point", message)

    def take_point(self, tid: str, stamp: int, frame: str, p: np.ndarray,
                           cov: np.ndarray) -> None:
        """Keep a target's camera point and covariance for its frame (a wrong frame or a
        NaN covariance is reported; its frame then misses the point and refuses the target,
        counted there)."""
        self.diag.count("target_points_received")
        if frame and frame.lstrip("/") != self.config.camera_frame:
            problem = f"frame {frame!r}, expected {self.config.camera_frame!r}"
        elif not np.isfinite(cov).all():
            problem = "covariance contains NaN"
        else:
            self.pipeline.add_target_point(tid, stamp, p, cov)
            return
        self.pipeline.target_point_arrived()
        self.diag.report("bad_target_point", f"targets/{tid}/point_cov: {problem}")

    def _on_markers(self, markers: list[tuple[Any, ...]]) -> None:
        """A frame's list of targets (``targets/markers``; its markers' fields,
        :data:`markers_decoder`)."""
        try:
            stamp, frame, spheres = spheres_from_marker_fields(markers)
        except ConversionError as exc:
            self._bad_markers(f"targets/markers: {exc}")
            return
        self.take_markers(stamp, frame, spheres)

    def _bad_markers(self, message: str) -> None:
        """A ``targets/markers`` message that lists no targets: counted and reported."""
        self.diag.count("target_frames")
        self.diag.report("bad_markers", message)

    def take_markers(self, stamp: int, frame: str, spheres: list[Sphere]) -> None:
        """A frame's list of targets: it waits for their points and the robot pose."""
        self.diag.count("target_frames")
        self._first_data(stamp)
        self.diag.count("target_points", len(spheres))
        if frame and frame.lstrip("/") != self.config.camera_frame:
            for s in spheres:
                self._refuse_target(s.id, "point_frame", f"targets/markers in frame {frame!r}, "
                                    f"expected {self.config.camera_frame!r}: ignored")
            return
        kept = []
        for s in spheres:
            reason = self._subscribe_target(s.id)
            if reason is None:
                kept.append(s)
            else:
                self._refuse_target(s.id, reason, f"target id {s.id!r}: " + (
                    "cannot name a topic" if reason == "bad_target_id" else
                    f"{self.config.max_targets} ids are subscribed already (max_targets)"))
        self.pipeline.add_frame(stamp, kept, received_ns=self._now_ns())
        self._arm_waits()

    def _refuse_target(self, tid: str, reason: str, message: str,
                       cause: str | None = None) -> None:
        """Count a listed target that gives no ``target/<id>/pose``."""
        self.diag.count("targets_rejected")
        self.diag.count(f"target_refused.{reason}")
        self.diag.report(cause or f"target_{reason}", message)

    # -- what the pipeline emits (every target) ---------------------------------------------
    def orphan_points(self, n: int) -> None:
        """Target points that no frame listed, dropped."""
        self.diag.count("orphan_target_points", n)

    def target_refused(self, f: WaitingFrame, s: Sphere, reason: str, detail: str) -> None:
        """A listed target that gives no ``target/<id>/pose``: counted and reported."""
        if reason == "no_point":
            self._refuse_target(s.id, reason, f"targets/{s.id}/point_cov at {f.stamp_ns} ns "
                                f"did not arrive within {self.config.max_target_wait_s} s")
        elif reason == "pending_overflow":
            self._refuse_target(s.id, reason, detail)
        elif reason == "bad_point_cov":
            self._refuse_target(s.id, reason, f"targets/{s.id}/point_cov at {f.stamp_ns} ns: "
                                f"{detail}")
        else:
            self._refuse_target(s.id, reason, f"no target/{s.id}/pose at {f.stamp_ns} ns: "
                                f"{detail}", cause="no_robot_pose")

    def target_located(self, f: WaitingFrame, s: Sphere, p: np.ndarray,
                       cov: np.ndarray) -> None:
        """A target in the base frame: ``target/<id>/pose(_cov)``; kept for the frame's
        outputs."""
        pubs = self._target_pubs[s.id]      # made with the subscription
        # volatile: unsubscribed messages reach no one, now or later (not built, not sent)
        want = (pubs[0].get_subscription_count() > 0, pubs[1].get_subscription_count() > 0)
        if any(want):
            pose_msg, cov_msg = self._point_pose(p, cov, f.stamp_ns, self.config.base_frame)
            if want[1]:
                pubs[1].publish(cov_msg)
            if want[0]:
                pubs[0].publish(pose_msg)
        self.diag.count("target_poses_published")
        self._located.append((s, p))
        cfg = self.config
        if cfg.target_frame_prefix:
            self._tf_edges.append((cfg.base_frame, cfg.target_frame_prefix + s.id, f.stamp_ns,
                                   p))

    def frame_done(self, f: WaitingFrame) -> None:
        """Every target of a frame went out: ``target/poses``, ``target/markers``, ``/tf``."""
        cfg = self.config
        located = self._located
        # serialized directly (ros.outputs_cdr: the bytes of ros.outputs' messages)
        if self.pub_poses.get_subscription_count() > 0:
            self.pub_poses.publish(pose_array_cdr([p for _, p in located], f.stamp_ns,
                                                  cfg.base_frame))
        if self.pub_markers.get_subscription_count() > 0:
            self.pub_markers.publish(sphere_markers_cdr(
                [Sphere(s.id, p, s.diameter_m, s.rgba) for s, p in located], f.stamp_ns,
                cfg.base_frame, cfg.marker_lifetime_s))
        self.diag.count("target_frames_published")
        self._tf_output.publish_edges(self._tf_edges)
        located.clear()
        self._tf_edges.clear()
