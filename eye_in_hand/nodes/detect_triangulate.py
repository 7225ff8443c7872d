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

# One BLAS thread in this process unless the user chose a count. OpenBLAS splits long dot
# products over a thread pool whose idle threads spin; on two cores also busy with other jobs
# the blob centre's (since computed without BLAS in core.detection) made a stereo pair cost
# 37 ms of CPU instead of 10 ms and the live latency 240 ms instead of 20 ms
# (docs/localization.md "Live latency"); one thread keeps any other long product in the node
# from doing the same. OpenBLAS reads the variable when numpy loads it, so this stands before
# the first numpy import of the node's process.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import math
import threading
import time
import traceback
from collections.abc import Callable, Mapping
from typing import Any

import cv2
import numpy as np
from geometry_msgs.msg import PointStamped, PoseWithCovarianceStamped
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image

from eye_in_hand.core.camera import StereoRig
from eye_in_hand.core.debug_image import draw_located_pair
from eye_in_hand.core.defaults import DEFAULT_SYNC_QUEUE_SIZE, DEFAULT_SYNC_SLOP_S
from eye_in_hand.core.locator import LocateResult, StereoLocator
from eye_in_hand.core.locator_params import (
    LOCATOR_PARAMETERS,
    TARGET_PARAMETERS,
    LocatorConfig,
    locator_config_from_params,
)
from eye_in_hand.core.sync import ApproximateStereoSync, StereoPair
from eye_in_hand.errors import ConfigError, ConversionError, EyeInHandError, InputError
from eye_in_hand.ros.camera_info import camera_info_to_model
from eye_in_hand.ros.diagnostics import ERROR, NodeDiagnostics
from eye_in_hand.ros.images import image_to_numpy, numpy_to_image
from eye_in_hand.ros.markers import Sphere, marker_classes, sphere_marker_array, sphere_style
from eye_in_hand.ros.names import topic_name_problem
from eye_in_hand.ros.node_main import run_node
from eye_in_hand.ros.outputs import (
    MARKER_DIAMETER_M,
    MARKER_LIFETIME_S,
    LocatedFrame,
    point_stamped,
    pose_with_covariance,
    rclpy_types,
)
from eye_in_hand.ros.params import Param, declare_params, param_from_spec
from eye_in_hand.ros.publishers import OutputPublishers
from eye_in_hand.ros.qos import RESULT_QOS, SENSOR_QOS, TARGET_POINT_QOS
from eye_in_hand.ros.queues import DropOldestQueue
from eye_in_hand.ros.stamps import header_stamp_ns

__all__ = ["NODE_PARAMETERS", "DetectTriangulateNode", "parameter_names", "parameter_hint",
           "main"]

NODE_NAME = "detect_triangulate"
#: A stamp this far behind the previous one on the same side is a time jump (bag loop, sim
#: reset), not an out-of-order frame: pairing restarts.
TIME_JUMP_BACK_NS = 1_000_000_000
DEFAULT_FRAME = "camera_left_optical_frame"
#: Encodings the detector accepts (converted to bgr8); anything else is "bad_encoding".
COLOR_ENCODINGS = ("bgr8", "rgb8", "bgra8", "rgba8", "bayer_rggb8", "bayer_bggr8",
                   "bayer_gbrg8", "bayer_grbg8", "8UC3")

#: Node-only parameters (the locator's are in :data:`eye_in_hand.core.locator`).
NODE_PARAMETERS: tuple[Param, ...] = (
    Param("calibration_dir", "", "directory with left.yaml + right.yaml (ROS camera_calibration "
          "files; stereo.yaml optional); empty = use the camera_info topics"),
    Param("frame_id", "", "frame of the published points; empty = the left image's frame_id "
          f"(or {DEFAULT_FRAME} when that is empty)"),
    Param("sync.slop_s", DEFAULT_SYNC_SLOP_S, "largest left/right stamp difference of a "
          "stereo pair (s); 0 = exact stamps only", range=(0.0, 1.0)),
    Param("sync.queue_size", DEFAULT_SYNC_QUEUE_SIZE, "frames per side waiting for a partner",
          range=(1, 100)),
    Param("queue_depth", 6, "stereo pairs waiting for the worker (6: 0.2 s at 30 Hz, enough "
          "for a burst of late DDS deliveries); when full the oldest is dropped (counted as "
          "dropped_pairs). 1 = only ever the newest pair", range=(1, 30)),
    Param("images.reliable", False, "subscribe to the images reliably: lost samples are sent "
          "again (a bag replay loses nothing in transport) but only reliable publishers "
          "match; false = best effort (sensor data QoS), which matches every camera driver"),
    Param("images.depth", 5, "images kept per side until the executor takes them (a busy "
          "machine may stall it for a few frames)", range=(1, 100)),
    Param("debug_image.max_rate_hz", 5.0, "rate limit of target/debug_image (Hz); 0 = never "
          "publish it", range=(0.0, 100.0)),
    Param("diagnostics_period_s", 1.0, "diagnostics publication period (s)",
          range=(0.05, 60.0)),
    Param("max_targets", 64, "most target ids that get targets/<id>/point(_cov) publishers; "
          "targets with further ids are refused (counted as targets_refused)",
          range=(1, 10_000)),
    Param("markers.lifetime_s", MARKER_LIFETIME_S, "lifetime of the spheres on "
          "targets/markers (s); 0 = until the next frame's DELETEALL", range=(0.0, 3600.0)),
    Param("markers.diameter_m", MARKER_DIAMETER_M, "sphere diameter on targets/markers for a "
          "target of unknown radius (radius_m 0)", range=(1e-4, 10.0)),
)


def _parameter_groups(target_names: Any) -> list[tuple[str, list[Param]]]:
    """``(prefix, parameters)`` the node declares: its own, the locator's, and one group
    ``targets.<name>.`` per entry of ``target_names``."""
    groups = [("", list(NODE_PARAMETERS)), ("", [param_from_spec(p) for p in LOCATOR_PARAMETERS])]
    for tname in target_names:
        groups.append((f"targets.{tname}.", [param_from_spec(p) for p in TARGET_PARAMETERS]))
    return groups


def parameter_names(values: Mapping[str, Any]) -> list[str]:
    """Every parameter name the node declares, given its parameter values (flat, dotted) from
    a parameter file: the per-target names follow ``target_names`` (default ``[red]``)."""
    names = values.get("target_names")
    if not isinstance(names, (list, tuple)):
        names = [p for p in LOCATOR_PARAMETERS if p.name == "target_names"][0].default
    return [prefix + p.name for prefix, group in _parameter_groups([str(n) for n in names])
            for p in group]


def parameter_hint(name: str, values: Mapping[str, Any]) -> str | None:
    """Advice for an undeclared ``targets.<name>.*``: its target is not in ``target_names``."""
    parts = name.split(".")
    if len(parts) != 3 or parts[0] != "targets":
        return None
    names = [p for p in LOCATOR_PARAMETERS if p.name == "target_names"][0].default
    names = values.get("target_names", names)
    if parts[1] in names:
        return None
    return (f"target '{parts[1]}' is not in target_names [{', '.join(map(str, names))}]: add it "
            "there, or remove its section (a node declares targets.<name>.* only for the "
            "names in target_names)")


class DetectTriangulateNode(Node):
    """Detect the configured coloured targets and publish their 3-D points.

    Args:
        **kwargs: passed to ``rclpy.node.Node`` (``context``, ``namespace``,
            ``parameter_overrides``, ...).

    Raises:
        ConfigError: a parameter is invalid (the message names it) or ``calibration_dir``
            cannot be loaded.
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        (_, own), (_, locator) = _parameter_groups(())
        node_values = declare_params(self, own)
        loc_values = declare_params(self, locator)
        flat: dict[str, Any] = dict(loc_values)
        for tname in loc_values["target_names"]:
            if not tname or not all(c.isalnum() or c == "_" for c in tname) \
                    or not tname[0].isalpha():
                raise ConfigError(f"parameter 'target_names': '{tname}' must start with a "
                                  "letter and contain only letters, digits and underscores")
            ((prefix, group),) = _parameter_groups((tname,))[2:]
            vals = declare_params(self, group, prefix=prefix)
            flat.update({f"{prefix}{k}": v for k, v in vals.items()})
        self.config: LocatorConfig = locator_config_from_params(flat)
        self._frame_id = str(node_values["frame_id"])
        self._debug_period = (1.0 / node_values["debug_image.max_rate_hz"]
                              if node_values["debug_image.max_rate_hz"] > 0 else math.inf)
        self._last_debug = -math.inf

        self._locator: StereoLocator | None = None
        self._from_files = bool(node_values["calibration_dir"])
        if self._from_files:
            rig = StereoRig.load(node_values["calibration_dir"])
            try:
                self._locator = StereoLocator(rig, self.config)
            except InputError as exc:
                raise ConfigError(f"calibration_dir '{node_values['calibration_dir']}': "
                                  f"{exc}") from exc
            self._locator.warm_up()
        self._info: dict[str, Any] = {"left": None, "right": None}
        self._info_key: tuple[Any, ...] | None = None
        self._lock = threading.Lock()

        slop_ns = int(round(node_values["sync.slop_s"] * 1e9))
        self._sync: ApproximateStereoSync[Image] = ApproximateStereoSync(
            slop_ns, node_values["sync.queue_size"])
        self._sync_seen = (0, 0)
        self._slot: DropOldestQueue[StereoPair[Image]] = DropOldestQueue(
            node_values["queue_depth"])
        self._queue_max = 0

        names = [t.name for t in self.config.detector.targets]
        # output publishers without per-publisher QoS-event handlers (a small wait set at every
        # executor wake-up); their subscribers' QoS is checked periodically instead
        self.outputs = OutputPublishers(self, lambda cause, text: self.diag.report(cause, text))
        self._pub_point = self.outputs.create(PointStamped, "target/point", RESULT_QOS)
        self._pub_point_cov = self.outputs.create(PoseWithCovarianceStamped, "target/point_cov",
                                                    RESULT_QOS)
        # per-target publishers, by target id: the configured names now, others when they
        # first appear (worker thread), at most max_targets ids
        self._max_targets = int(node_values["max_targets"])
        self._pub_targets: dict[str, tuple[Any, Any]] = {}
        self._pub_targets_lock = threading.Lock()
        self._marker_lifetime_s = float(node_values["markers.lifetime_s"])
        self._marker_diameter_m = float(node_values["markers.diameter_m"])
        self._specs = {t.name: t for t in self.config.detector.targets}
        self._styles: dict[str, tuple[float, tuple[float, float, float, float]]] = {}
        self._pub_markers = self.outputs.create(marker_classes()[1], "targets/markers",
                                                  RESULT_QOS)
        # targets/<id>/... live next to targets/markers, wherever a remapping put it (launch
        # remaps it to the root namespace: dynamic ids cannot be remapped one by one)
        self._targets_prefix = self.resolve_topic_name("targets/markers").rsplit("/", 1)[0]
        self._pub_debug = self.outputs.create(Image, "target/debug_image", SENSOR_QOS)
        self.diag = NodeDiagnostics(self, period_s=node_values["diagnostics_period_s"])
        self.diag.declare_counter("pairs", "detections", "dropped_pairs", "sync_dropped",
                                  "left_frames", "right_frames", "sync_pairs",
                                  "sync_unpaired_left", "sync_unpaired_right",
                                  "points_published", "no_target", "failed_pairs",
                                  "targets_located", "target_points_published",
                                  "targets_refused", "marker_frames")
        for n in names:
            self._target_publishers(n)
        self.diag.warn_above("processing_ms", 50.0)
        self.diag.stale_after("pairs", 5.0)  # WARN when no stereo pair arrived for 5 s

        image_qos = QoSProfile(depth=int(node_values["images.depth"]),
                               history=HistoryPolicy.KEEP_LAST,
                               reliability=ReliabilityPolicy.RELIABLE
                               if node_values["images.reliable"] else SENSOR_QOS.reliability,
                               durability=SENSOR_QOS.durability)
        self.create_subscription(Image, "left/image_raw", self._on_left, image_qos,
                                 event_callbacks=self._image_qos_events("left/image_raw"))
        self.create_subscription(Image, "right/image_raw", self._on_right, image_qos,
                                 event_callbacks=self._image_qos_events("right/image_raw"))
        if not self._from_files:
            self.create_subscription(CameraInfo, "left/camera_info",
                                     lambda m: self._on_info("left", m), SENSOR_QOS)
            self.create_subscription(CameraInfo, "right/camera_info",
                                     lambda m: self._on_info("right", m), SENSOR_QOS)

        #: called on the worker thread with each located pair, after its topics are sent
        #: (``hand_eye`` in the same process: :mod:`eye_in_hand.nodes.localize`)
        self.frame_sinks: list[Callable[[LocatedFrame], None]] = []
        self._worker = threading.Thread(target=self._work, name=f"{NODE_NAME}_worker",
                                         daemon=True)
        self._worker.start()
        self.get_logger().info(
            f"detecting {names} with method '{self.config.method}', calibration from "
            f"{node_values['calibration_dir'] or 'camera_info topics'}")

    # -- executor-thread callbacks (cheap) -------------------------------------------------
    def _on_left(self, msg: Image) -> None:
        self._on_image(0, msg)

    def _on_right(self, msg: Image) -> None:
        self._on_image(1, msg)

    def _on_image(self, side: int, msg: Image) -> None:
        topic = ("left", "right")[side] + "/image_raw"
        self.diag.count(f"{('left', 'right')[side]}_frames")
        try:
            stamp = header_stamp_ns(msg)
        except ConversionError as exc:
            self.diag.count(f"sync_unpaired_{('left', 'right')[side]}")
            self.diag.report("bad_image", f"{topic}: {exc}")
            return
        last = self._sync.last_stamps[side]
        if last is not None and last - stamp > TIME_JUMP_BACK_NS:
            # A bag replay restarted (--loop) or simulated time was reset: start pairing afresh
            # instead of rejecting every frame until the stamps catch up.
            self.get_logger().info(f"{topic}: time jumped back {(last - stamp) / 1e9:.3f} s: "
                                   "stereo pairing and tracking reset")
            self._count_unpaired(*self._sync.pending)   # frames waiting in the sync are lost
            self._sync.reset()
            self._sync_seen = (self._sync.stats.dropped, self._sync.stats.dropped_stale)
            self.diag.count("time_jumps")
        pairs = (self._sync.push_left if side == 0 else self._sync.push_right)(stamp, msg)
        stats = self._sync.stats
        seen = (stats.dropped, stats.dropped_stale)
        self._count_sync_drops()
        if seen != self._sync_seen:
            self.diag.count("sync_dropped", seen[0] - self._sync_seen[0])
            if seen[1] > self._sync_seen[1]:
                self.diag.report("stale_stamp", f"{topic}: stamp {stamp} ns is not after the "
                                 "previous frame's on the same side (out of order or repeated)")
            if seen[0] - seen[1] > self._sync_seen[0] - self._sync_seen[1]:
                self.diag.report(
                    "unsynchronised", f"left/right frames without a partner within "
                    f"{self._sync.slop_ns / 1e6:.3f} ms were dropped (last stamp {stamp} ns on "
                    f"{topic})")
            self._sync_seen = seen
        for pair in pairs:
            self.diag.count("sync_pairs")
            if self._slot.put(pair):
                self.diag.count("dropped_pairs")
            waiting = len(self._slot)
            if waiting > self._queue_max:     # the most pairs ever waiting: sizes queue_depth
                self._queue_max = waiting
                self.diag.gauge("queue_max", waiting)
        self._ledger_gauges()

    _sync_sides_seen = (0, 0)

    def _count_sync_drops(self) -> None:
        """Frames the stereo sync dropped since the last call, per side."""
        stats = self._sync.stats
        now = (stats.dropped_left, stats.dropped_right)
        self._count_unpaired(now[0] - self._sync_sides_seen[0],
                             now[1] - self._sync_sides_seen[1])
        self._sync_sides_seen = now

    def _count_unpaired(self, left: int, right: int) -> None:
        if left:
            self.diag.count("sync_unpaired_left", left)
        if right:
            self.diag.count("sync_unpaired_right", right)

    def _ledger_gauges(self) -> None:
        """What is still in flight, so the counters reconcile at any moment; and the one loss
        total, ``frames_lost``: images without a partner (``stale_stamp`` ones among them,
        also counted on their own as ``sync_stale``), pairs dropped from the queue and pairs
        that failed."""
        pending = self._sync.pending
        self.diag.gauge("sync_pending_left", pending[0])
        self.diag.gauge("sync_pending_right", pending[1])
        self.diag.gauge("queued", len(self._slot))
        self.diag.gauge("sync_stale", self._sync.stats.dropped_stale)
        self.diag.gauge("frames_lost", sum(self.diag.counter(k) for k in (
            "sync_unpaired_left", "sync_unpaired_right", "dropped_pairs", "failed_pairs")))

    def _on_info(self, side: str, msg: CameraInfo) -> None:
        with self._lock:
            self._info[side] = msg

    # -- worker thread ---------------------------------------------------------------------
    def _work(self) -> None:
        while not self._slot.stopped:
            pair = self._slot.take(0.1)
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
            self._ledger_gauges()
            self.diag.gauge("processing_ms", (time.perf_counter() - t0) * 1e3)

    def _current_locator(self) -> StereoLocator | None:
        if self._from_files:
            return self._locator
        with self._lock:
            left, right = self._info["left"], self._info["right"]
        if left is None or right is None:
            missing = [s for s, m in (("left", left), ("right", right)) if m is None]
            self.diag.report("no_camera_info", f"no camera_info received on "
                             f"{', '.join(f'{s}/camera_info' for s in missing)} yet: "
                             "pairs are skipped until it arrives")
            return None
        key = tuple((m.width, m.height, m.distortion_model, tuple(m.d), tuple(m.k), tuple(m.r),
                     tuple(m.p)) for m in (left, right))
        if key != self._info_key:
            try:
                lm = camera_info_to_model(left, name="left")
                rm = camera_info_to_model(right, name="right")
                rig = StereoRig.from_ros_pair(lm, rm, source="left/right camera_info")
                self._locator = StereoLocator(rig, self.config)
                self._locator.warm_up()
            except (ConversionError, ConfigError, InputError) as exc:
                self._locator = None
                self.diag.report("bad_camera_info", f"camera_info: {exc}")
            self._info_key = key
        if self._locator is None:
            self.diag.report("bad_camera_info", "camera_info does not describe a usable "
                             "calibrated stereo pair: pairs are skipped")
        return self._locator

    def _image(self, msg: Image, topic: str, size: tuple[int, int]) -> np.ndarray | None:
        if msg.encoding not in COLOR_ENCODINGS:
            self.diag.report("bad_encoding", f"{topic}: encoding '{msg.encoding}' is not a "
                             f"colour image (accepted: {', '.join(COLOR_ENCODINGS)})")
            return None
        if (msg.width, msg.height) != size:
            self.diag.report("size_mismatch", f"{topic}: image is {msg.width}x{msg.height} but "
                             f"the calibration is {size[0]}x{size[1]}")
            return None
        try:
            enc = "bgr8" if msg.encoding != "8UC3" else None
            img = image_to_numpy(msg, desired_encoding=enc)
        except ConversionError as exc:
            self.diag.report("bad_image", f"{topic}: {exc}")
            return None
        return np.ascontiguousarray(img)

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

    def _process(self, pair: StereoPair[Image]) -> str:
        """Locate and publish one pair; the ledger counter of its outcome
        (``points_published``, ``no_target`` or ``failed_pairs``)."""
        self.diag.count("pairs")
        locator = self._current_locator()
        if locator is None:
            return "failed_pairs"
        rig = locator.rig
        left = self._image(pair.left, "left/image_raw", rig.left.size)
        right = self._image(pair.right, "right/image_raw", rig.right.size)
        if left is None or right is None:
            return "failed_pairs"
        result = locator.locate(left, right)
        stamp = pair.stamp_ns
        frame = self._frame_id or pair.left.header.frame_id or DEFAULT_FRAME
        first = result.first
        first_msgs = None
        if first is not None:
            # The covariance first: hand_eye pairs the two by stamp and waits for the point.
            # The same two messages go to targets/<first id>/... below (built once).
            first_msgs = (pose_with_covariance(rclpy_types(), first.point_m, first.covariance,
                                               stamp, frame),
                          point_stamped(rclpy_types(), first.point_m, stamp, frame))
            # volatile topics: a message nobody subscribes to reaches no one, now or later
            # (as in hand_eye); the transient-local targets/<id>/... below always go out
            if self._pub_point_cov.get_subscription_count() > 0:
                self._pub_point_cov.publish(first_msgs[0])
            if self._pub_point.get_subscription_count() > 0:
                self._pub_point.publish(first_msgs[1])
            self.diag.count("detections")
            self.diag.gauge("residual_px", float(first.residual_px))
            self.diag.gauge("sigma_z_mm", float(math.sqrt(first.covariance[2, 2]) * 1e3))
            self.diag.gauge("range_m", float(np.linalg.norm(first.point_m)))
        else:
            self.diag.gauge("last_miss", result.rejected.get(result.first_name, ""))
        delivered = self._publish_targets(result, stamp, frame, first_msgs)
        if self.frame_sinks:
            located = LocatedFrame(
                stamp, frame, None if first is None else (first.point_m, first.covariance),
                tuple(delivered))
            for sink in self.frame_sinks:
                sink(located)
        n_pairs = self.diag.counter("pairs")
        self.diag.gauge("detection_rate", self.diag.counter("detections") / max(1, n_pairs))
        try:
            self._maybe_debug(left, right, result, pair)
        except (EyeInHandError, cv2.error, ValueError) as exc:  # the point is out already
            self.diag.report("debug_image", f"target/debug_image: {exc}")
        return "points_published" if first is not None else "no_target"

    @property
    def target_ids(self) -> list[str]:
        """The target ids that have publishers (the configured names from the start)."""
        with self._pub_targets_lock:
            return list(self._pub_targets)

    def _target_publishers(self, tid: str) -> tuple[Any, Any] | None:
        """``(point, point_cov)`` publishers of ``targets/<tid>/...``, made on first use; None
        (reported) when ``tid`` is no valid topic token or ``max_targets`` ids have some."""
        with self._pub_targets_lock:
            pubs = self._pub_targets.get(tid)
            if pubs is not None:
                return pubs
            problem = topic_name_problem(f"targets/{tid}/point") if tid and "/" not in tid \
                else "empty or contains '/'"
            if problem is not None:
                self.diag.report("bad_target_id", f"target id {tid!r} cannot name a topic "
                                 f"({problem}): not published")
                return None
            if len(self._pub_targets) >= self._max_targets:
                self.diag.report("too_many_targets", f"target id {tid!r}: {self._max_targets} "
                                 "ids have publishers already (max_targets): not published")
                return None
            base = f"{self._targets_prefix}/{tid}"
            pubs = (self.outputs.create(PointStamped, f"{base}/point", TARGET_POINT_QOS),
                    self.outputs.create(PoseWithCovarianceStamped, f"{base}/point_cov",
                                        TARGET_POINT_QOS))
            self._pub_targets[tid] = pubs
            return pubs

    def _publish_targets(self, result: LocateResult, stamp: int, frame: str,
                         first_msgs: tuple[Any, Any] | None = None
                         ) -> list[tuple[Sphere, np.ndarray]]:
        """Every located target on its own topics, then the frame's ``targets/markers``.
        ``first_msgs``: the ``(point_cov, point)`` messages already built for
        ``result.first`` (``target/point_cov``, ``target/point``), sent again as they are.
        Returns each published target's sphere (as on ``targets/markers``) and covariance."""
        spheres = []
        delivered = []
        for t in result.targets:
            self.diag.count("targets_located")
            pubs = self._target_publishers(t.id)
            if pubs is None:
                self.diag.count("targets_refused")
                continue
            if first_msgs is not None and t is result.first:
                cov_msg, point_msg = first_msgs
            else:
                cov_msg = pose_with_covariance(rclpy_types(), t.point_m, t.covariance, stamp,
                                               frame)
                point_msg = point_stamped(rclpy_types(), t.point_m, stamp, frame)
            pubs[1].publish(cov_msg)
            pubs[0].publish(point_msg)
            self.diag.count("target_points_published")
            diameter, rgba = self._sphere_style(t.name)
            spheres.append(Sphere(t.id, t.point_m, diameter, rgba))
            delivered.append((spheres[-1], t.covariance))
        if self._pub_markers.get_subscription_count() > 0:     # volatile, as above
            self._pub_markers.publish(sphere_marker_array(
                spheres, stamp_ns=stamp, frame_id=frame, lifetime_s=self._marker_lifetime_s))
        self.diag.count("marker_frames")
        return delivered

    def _sphere_style(self, name: str) -> tuple[float, tuple[float, float, float, float]]:
        """Diameter (m) and RGBA of a target's sphere on ``targets/markers`` (per name, cached:
        they depend on the configuration only)."""
        style = self._styles.get(name)
        if style is None:
            spec = self._specs.get(name)
            style = self._styles[name] = sphere_style(
                spec.radius_m if spec is not None else None,
                spec.color if spec is not None else None, self._marker_diameter_m)
        return style

    def _maybe_debug(self, left: np.ndarray, right: np.ndarray, result: LocateResult,
                     pair: StereoPair[Image]) -> None:
        now = time.monotonic()
        if now - self._last_debug < self._debug_period or \
                self._pub_debug.get_subscription_count() == 0:
            return
        self._last_debug = now
        canvas = draw_located_pair(left, right, result)
        self._pub_debug.publish(numpy_to_image(canvas, "bgr8", stamp_ns=pair.stamp_ns,
                                               frame_id=pair.left.header.frame_id))

    # -- teardown --------------------------------------------------------------------------
    def destroy_node(self) -> None:
        """Stop the worker thread, then destroy the node."""
        self._slot.stop()
        if self._worker.is_alive():
            self._worker.join(timeout=5.0)
        self.diag.destroy()
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    """Console entry point: ``ros2 run eye_in_hand detect_triangulate``."""
    run_node("detect_triangulate", DetectTriangulateNode, args)


if __name__ == "__main__":
    main()
