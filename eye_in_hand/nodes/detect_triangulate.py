"""The ``detect_triangulate`` node: coloured targets in stereo pairs -> 3-D points.

Subscribes (relative names, :data:`~eye_in_hand.ros.qos.SENSOR_QOS`):
    ``left/image_raw``, ``right/image_raw`` (sensor_msgs/Image: bgr8, rgb8, bgra8, rgba8 or an
    8-bit Bayer mosaic), ``left/camera_info``, ``right/camera_info`` (sensor_msgs/CameraInfo,
    ignored when ``calibration_dir`` is set).

Publishes:
    ``target/point`` (geometry_msgs/PointStamped, RESULT_QOS): the first configured target, in
    the left optical frame, stamped with the left image's stamp; nothing when it is not found.
    ``target/point``, ``target/point_cov`` and ``targets/markers`` are volatile: a message
    is built and sent only while someone subscribes (counted all the same).
    ``target/point_cov`` (geometry_msgs/PoseWithCovarianceStamped, RESULT_QOS): the same point
    with its triangulation covariance (position block, m^2; orientation variances 1e6),
    published just before ``target/point``; ``hand_eye`` propagates it into ``target/pose_cov``.
    ``targets/<id>/point`` (PointStamped) and ``targets/<id>/point_cov``
    (PoseWithCovarianceStamped, published just before the point), both TARGET_POINT_QOS
    (reliable, transient local, keep last 100: a subscriber made when an id first appears
    still gets that id's first points): every located
    target, ``<id>`` its :attr:`~eye_in_hand.core.locator.TargetLocation.id` (the target name
    for a one-blob target, ``<name>_<k>`` for blob sets of one colour). The publishers of the
    configured names exist from start-up; other ids get theirs when they first appear, at most
    ``max_targets`` ids in all; they sit next to ``targets/markers`` (a remapping of that topic
    moves them all: ids appear at run time and cannot be remapped one by one). An id that is
    not a valid topic token or over that bound is refused (counted as ``targets_refused``,
    logged once).
    ``targets/markers`` (visualization_msgs/MarkerArray, RESULT_QOS): per processed pair, a
    DELETEALL then one SPHERE per published target (``ns`` = id, diameter from the target's
    radius, colour from its colour range), left optical frame, image stamp
    (:mod:`eye_in_hand.ros.markers`); ``hand_eye`` reads it as the frame's list of targets.
    ``target/debug_image`` (sensor_msgs/Image bgr8, half size, left|right side by side with the
    detections drawn): only while someone subscribes, at most ``debug_image.max_rate_hz``.
    ``diagnostics`` (diagnostic_msgs/DiagnosticArray): pairs, detections, detection rate,
    residual, covariance, dropped pairs, sync drops, processing time, bad-input causes, and
    the loss ledger below.

Every frame is accounted for on ``diagnostics`` (counters since start; see docs/localization.md
"Losses and staleness")::

    left_frames  = sync_pairs + sync_unpaired_left  + sync_pending_left   (gauge)
    right_frames = sync_pairs + sync_unpaired_right + sync_pending_right  (gauge)
    sync_pairs   = dropped_pairs + pairs + queued                         (gauge)
    frames_lost  = sync_unpaired_left + sync_unpaired_right + dropped_pairs + failed_pairs
                   (gauge: the one loss total; sync_stale of the unpaired had a stamp not
                   after their side's previous one, e.g. a replay right after a run)
    pairs        = points_published + no_target + failed_pairs
    targets_located = target_points_published + targets_refused
    marker_frames   = points_published + no_target      (one targets/markers per located pair)

``points_published`` is what ``hand_eye`` should receive: its ``points`` counter is the other
end, and the difference is lost between the nodes.

Processing runs on a worker thread, never on the executor thread: the image callbacks only
pair frames (:class:`~eye_in_hand.core.sync.ApproximateStereoSync`) and queue the pair for the
worker; at most ``queue_depth`` pairs wait, and a pair arriving at a full queue drops the oldest
one (counted), so a stall of the worker costs latency for a few frames, not frames, and the
node never lags far behind the cameras.

Bad input (wrong encoding, size disagreeing with camera_info, empty or truncated data,
unsynchronised frames, missing camera_info) is logged once per cause, counted on
``diagnostics``, publishes nothing for that pair, and the node keeps running.
"""
from __future__ import annotations

import os

from eye_in_hand.threads import blas_env_defaults, name_os_thread  # no numpy loaded here

# One BLAS thread unless the user chose a count: OpenBLAS's pool threads spin, and on two busy
# cores a long product once made a pair cost 37 ms of CPU instead of 10 and the latency 240 ms
# instead of 20 (docs/localization.md "Live latency"). OpenBLAS reads the variable when numpy
# loads, so this stands before the first numpy import of the node's process.
os.environ.update(blas_env_defaults(os.environ))

import math
import threading
import time
import traceback
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image

from eye_in_hand.core.sync import ApproximateStereoSync, StereoPair
from eye_in_hand.errors import EyeInHandError
from eye_in_hand.nodes.detect_triangulate_inputs import LocatorSource, StereoIntake, color_image
from eye_in_hand.nodes.detect_triangulate_outputs import TargetPublishers
from eye_in_hand.nodes.detect_triangulate_params import DEFAULT_FRAME, declare_parameters
from eye_in_hand.ros.diagnostics import ERROR, NodeDiagnostics
from eye_in_hand.ros.node_main import run_node
from eye_in_hand.ros.outputs import LocatedFrame
from eye_in_hand.ros.publishers import OutputPublishers
from eye_in_hand.ros.qos import SENSOR_QOS
from eye_in_hand.ros.queues import DropOldestQueue

__all__ = ["DetectTriangulateNode", "main"]

NODE_NAME = "detect_triangulate"
#: the worker thread's name, also for the OS (``top -H``; eye_in_hand.threads.name_os_thread)
WORKER_THREAD_NAME = "detect_worker"


class DetectTriangulateNode(Node):
    """Detect the configured coloured targets and publish their 3-D points.

    Its parameters are in :mod:`eye_in_hand.nodes.detect_triangulate_params`, its inputs
    (stereo pairing, the locator of the current calibration) in
    :mod:`eye_in_hand.nodes.detect_triangulate_inputs`, its outputs in
    :mod:`eye_in_hand.nodes.detect_triangulate_outputs`; the node wires them up and runs the
    worker thread that hands each stereo pair to the locator.

    Args:
        **kwargs: passed to ``rclpy.node.Node`` (``context``, ``namespace``,
            ``parameter_overrides``, ...).

    Raises:
        ConfigError: a parameter is invalid (the message names it) or ``calibration_dir``
            cannot be loaded.
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        values, self.config = declare_parameters(self)
        self._frame_id = str(values["frame_id"])
        self.diag = NodeDiagnostics(self, period_s=values["diagnostics_period_s"])
        self.diag.declare_counter("pairs", "detections", "dropped_pairs", "sync_dropped",
                                  "left_frames", "right_frames", "sync_pairs",
                                  "sync_unpaired_left", "sync_unpaired_right",
                                  "points_published", "no_target", "failed_pairs",
                                  "targets_located", "target_points_published",
                                  "targets_refused", "marker_frames")
        self.diag.warn_above("processing_ms", 50.0)
        self.diag.stale_after("pairs", 5.0)  # WARN when no stereo pair arrived for 5 s
        self.locators = LocatorSource(self.config, self.diag, str(values["calibration_dir"]))
        slop_ns = int(round(values["sync.slop_s"] * 1e9))
        self._queue: DropOldestQueue[StereoPair[Image]] = DropOldestQueue(values["queue_depth"])
        self.intake = StereoIntake(ApproximateStereoSync(slop_ns, values["sync.queue_size"]),
                                   self._queue, self.diag, self.get_logger().info)
        # output publishers without per-publisher QoS-event handlers (a small wait set at every
        # executor wake-up); their subscribers' QoS is checked periodically instead
        self.outputs = OutputPublishers(self, self.diag.report)
        # targets/<id>/... live next to targets/markers, wherever a remapping put it (launch
        # remaps it to the root namespace: dynamic ids cannot be remapped one by one)
        self.targets = TargetPublishers(
            self.outputs.create, self.diag,
            self.resolve_topic_name("targets/markers").rsplit("/", 1)[0],
            self.config.detector.targets, max_targets=values["max_targets"],
            marker_lifetime_s=values["markers.lifetime_s"],
            marker_diameter_m=values["markers.diameter_m"],
            debug_rate_hz=values["debug_image.max_rate_hz"])
        self._subscribe(values)
        #: called on the worker thread with each located pair, after its topics are sent
        #: (``hand_eye`` in the same process: :mod:`eye_in_hand.nodes.localize`)
        self.frame_sinks: list[Callable[[LocatedFrame], None]] = []
        self._worker = threading.Thread(target=self._work, name=WORKER_THREAD_NAME,
                                         daemon=True)
        self._worker.start()
        self.get_logger().info(
            f"detecting {[t.name for t in self.config.detector.targets]} with method "
            f"'{self.config.method}', calibration from "
            f"{values['calibration_dir'] or 'camera_info topics'}")

    def _subscribe(self, values: dict[str, Any]) -> None:
        """The image subscriptions (QoS from ``images.*``) and, without ``calibration_dir``,
        the camera_info ones."""
        image_qos = QoSProfile(depth=int(values["images.depth"]),
                               history=HistoryPolicy.KEEP_LAST,
                               reliability=ReliabilityPolicy.RELIABLE
                               if values["images.reliable"] else SENSOR_QOS.reliability,
                               durability=SENSOR_QOS.durability)
        self.create_subscription(Image, "left/image_raw", self.intake.on_left, image_qos,
                                 event_callbacks=self._image_qos_events("left/image_raw"))
        self.create_subscription(Image, "right/image_raw", self.intake.on_right, image_qos,
                                 event_callbacks=self._image_qos_events("right/image_raw"))
        if not self.locators.from_files:
            self.create_subscription(CameraInfo, "left/camera_info",
                                     lambda m: self.locators.on_info("left", m), SENSOR_QOS)
            self.create_subscription(CameraInfo, "right/camera_info",
                                     lambda m: self.locators.on_info("right", m), SENSOR_QOS)

    def _image_qos_events(self, topic: str) -> Any:
        """A camera whose publisher cannot match the image subscription's QoS (a best-effort
        driver with ``images.reliable: true``) sends this node nothing: say so, with the fix,
        in the log and on diagnostics, instead of waiting silently."""
        from rclpy.event_handler import SubscriptionEventCallbacks

        def incompatible(info: Any) -> None:
            self.diag.report(
                "image_qos", f"{self.resolve_topic_name(topic)}: a publisher offers a QoS this "
                f"subscription cannot match (policy {info.last_policy_kind}): it sends no "
                "images here; with a best-effort camera driver set images.reliable: false",
                level=ERROR)

        return SubscriptionEventCallbacks(incompatible_qos=incompatible)

    @property
    def target_ids(self) -> list[str]:
        """The target ids that have publishers (the configured names from the start)."""
        return self.targets.target_ids

    # -- worker thread ---------------------------------------------------------------------
    def _work(self) -> None:
        name_os_thread()      # its Python name for the OS: its CPU apart from the executor's
        while not self._queue.stopped:
            pair = self._queue.take(0.1)
            if pair is None:
                continue
            if not self.context.ok():
                break  # shutting down (e.g. Ctrl-C shut the context down under us)
            t0 = time.perf_counter()
            try:
                outcome = self._process(pair)
            except EyeInHandError as exc:  # per-pair input problems: counted, node keeps going
                outcome = "failed_pairs"
                self.diag.report(type(exc).__name__, str(exc))
            except Exception as exc:  # noqa: BLE001 - a bug must not stop the stream silently:
                if not self.context.ok():
                    break  # publishing raced with the context's shutdown: nothing to report
                # logged with its traceback (first occurrence) and counted at ERROR level
                outcome = "failed_pairs"
                self.diag.report("internal_error", f"{type(exc).__name__}: {exc}\n"
                                 f"{traceback.format_exc()}", level=ERROR)
            self.diag.count(outcome)
            self.intake.ledger_gauges()
            self.diag.gauge("processing_ms", (time.perf_counter() - t0) * 1e3)

    def _process(self, pair: StereoPair[Image]) -> str:
        """Locate and publish one pair; the ledger counter of its outcome
        (``points_published``, ``no_target`` or ``failed_pairs``)."""
        self.diag.count("pairs")
        locator = self.locators.current()
        if locator is None:
            return "failed_pairs"
        rig = locator.rig
        left = color_image(pair.left, "left/image_raw", rig.left.size, self.diag)
        right = color_image(pair.right, "right/image_raw", rig.right.size, self.diag)
        if left is None or right is None:
            return "failed_pairs"
        result = locator.locate(left, right)
        stamp = pair.stamp_ns
        frame = self._frame_id or pair.left.header.frame_id or DEFAULT_FRAME
        first = result.first
        delivered = self.targets.publish(result, stamp, frame)
        if first is not None:
            self.diag.count("detections")
            self.diag.gauge("residual_px", float(first.residual_px))
            self.diag.gauge("sigma_z_mm", float(math.sqrt(first.covariance[2, 2]) * 1e3))
            self.diag.gauge("range_m", float(np.linalg.norm(first.point_m)))
        else:
            self.diag.gauge("last_miss", result.rejected.get(result.first_name, ""))
        if self.frame_sinks:
            located = LocatedFrame(
                stamp, frame, None if first is None else (first.point_m, first.covariance),
                tuple(delivered))
            for sink in self.frame_sinks:
                sink(located)
        n_pairs = self.diag.counter("pairs")
        self.diag.gauge("detection_rate", self.diag.counter("detections") / max(1, n_pairs))
        try:
            self.targets.publish_debug(left, right, result, stamp, pair.left.header.frame_id)
        except (EyeInHandError, cv2.error, ValueError) as exc:  # the point is out already
            self.diag.report("debug_image", f"target/debug_image: {exc}")
        return "points_published" if first is not None else "no_target"

    # -- teardown --------------------------------------------------------------------------
    def destroy_node(self) -> None:
        """Stop the worker thread, then destroy the node."""
        self._queue.stop()
        if self._worker.is_alive():
            self._worker.join(timeout=5.0)
        self.diag.destroy()
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    """Console entry point: ``ros2 run eye_in_hand detect_triangulate``."""
    run_node("detect_triangulate", DetectTriangulateNode, args)


if __name__ == "__main__":
    main()
