"""The ``detect_triangulate`` node's inputs: stereo pairing with its ledger, and the locator.

Parts of :class:`eye_in_hand.nodes.detect_triangulate.DetectTriangulateNode` (objects with
explicit constructor arguments):

* :class:`StereoIntake` runs on the executor thread: it pairs the left and right images
  (:class:`~eye_in_hand.core.sync.ApproximateStereoSync`), puts each pair on the worker's
  :class:`~eye_in_hand.ros.queues.DropOldestQueue` and counts every frame on the node's
  diagnostics (the loss ledger of the node's docstring);
* :class:`LocatorSource` gives the worker the
  :class:`~eye_in_hand.core.locator.StereoLocator` of the current calibration: from
  ``calibration_dir`` once, or rebuilt whenever the ``camera_info`` pair changes;
* :func:`color_image` turns an image message into the BGR array the locator takes.
"""
from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import numpy as np
from sensor_msgs.msg import CameraInfo, Image

from eye_in_hand.core.camera import StereoRig
from eye_in_hand.core.locator import StereoLocator
from eye_in_hand.core.locator_params import LocatorConfig
from eye_in_hand.core.sync import ApproximateStereoSync, StereoPair
from eye_in_hand.errors import ConfigError, ConversionError, InputError
from eye_in_hand.ros.camera_info import camera_info_to_model
from eye_in_hand.ros.images import image_to_numpy
from eye_in_hand.ros.queues import DropOldestQueue
from eye_in_hand.ros.stamps import header_stamp_ns

__all__ = ["TIME_JUMP_BACK_NS", "COLOR_ENCODINGS", "StereoIntake", "LocatorSource",
           "color_image"]

#: A stamp this far behind the previous one on the same side is a time jump (bag loop, sim
#: reset), not an out-of-order frame: pairing restarts.
TIME_JUMP_BACK_NS = 1_000_000_000
#: Encodings the detector accepts (converted to bgr8); anything else is "bad_encoding".
COLOR_ENCODINGS = ("bgr8", "rgb8", "bgra8", "rgba8", "bayer_rggb8", "bayer_bggr8",
                   "bayer_gbrg8", "bayer_grbg8", "8UC3")

_SIDES = ("left", "right")


class StereoIntake:
    """Images in (executor thread), stereo pairs out to the worker's queue, every frame counted.

    Args:
        sync: the stereo pairing.
        queue: the hand-over to the worker (drops the oldest pair when full).
        diag: the node's diagnostics (the ledger counters and gauges, bad-input causes).
        log: the node's info log (a time jump back).
    """

    def __init__(self, sync: ApproximateStereoSync[Image],
                 queue: DropOldestQueue[StereoPair[Image]], diag: Any,
                 log: Callable[[str], Any]) -> None:
        self.sync = sync
        self._queue = queue
        self._diag = diag
        self._log = log
        self._sync_seen = (0, 0)          # sync drops (all, stale) already reported
        self._sync_sides_seen = (0, 0)    # sync drops (left, right) already counted
        self._queue_max = 0

    def on_left(self, msg: Image) -> None:
        self._on_image(0, msg)

    def on_right(self, msg: Image) -> None:
        self._on_image(1, msg)

    def _on_image(self, side: int, msg: Image) -> None:
        topic = _SIDES[side] + "/image_raw"
        self._diag.count(f"{_SIDES[side]}_frames")
        try:
            stamp = header_stamp_ns(msg)
        except ConversionError as exc:
            self._diag.count(f"sync_unpaired_{_SIDES[side]}")
            self._diag.report("bad_image", f"{topic}: {exc}")
            return
        last = self.sync.last_stamps[side]
        if last is not None and last - stamp > TIME_JUMP_BACK_NS:
            self._restart(topic, last - stamp)
        pairs = (self.sync.push_left if side == 0 else self.sync.push_right)(stamp, msg)
        self._count_sync_drops()
        self._report_sync_drops(topic, stamp)
        for pair in pairs:
            self._diag.count("sync_pairs")
            if self._queue.put(pair):
                self._diag.count("dropped_pairs")
            waiting = len(self._queue)
            if waiting > self._queue_max:     # the most pairs ever waiting: sizes queue_depth
                self._queue_max = waiting
                self._diag.gauge("queue_max", waiting)
        self.ledger_gauges()

    def _restart(self, topic: str, back_ns: int) -> None:
        """A bag replay restarted (--loop) or simulated time was reset: start pairing afresh
        instead of rejecting every frame until the stamps catch up."""
        self._log(f"{topic}: time jumped back {back_ns / 1e9:.3f} s: "
                  "stereo pairing and tracking reset")
        self._count_unpaired(*self.sync.pending)   # frames waiting in the sync are lost
        self.sync.reset()
        self._sync_seen = (self.sync.stats.dropped, self.sync.stats.dropped_stale)
        self._diag.count("time_jumps")

    def _report_sync_drops(self, topic: str, stamp: int) -> None:
        """Count the frames the sync dropped since the last image; report stale and
        unsynchronised ones (once per cause)."""
        stats = self.sync.stats
        seen = (stats.dropped, stats.dropped_stale)
        if seen == self._sync_seen:
            return
        self._diag.count("sync_dropped", seen[0] - self._sync_seen[0])
        if seen[1] > self._sync_seen[1]:
            self._diag.report("stale_stamp", f"{topic}: stamp {stamp} ns is not after the "
                              "previous frame's on the same side (out of order or repeated)")
        if seen[0] - seen[1] > self._sync_seen[0] - self._sync_seen[1]:
            self._diag.report(
                "unsynchronised", f"left/right frames without a partner within "
                f"{self.sync.slop_ns / 1e6:.3f} ms were dropped (last stamp {stamp} ns on "
                f"{topic})")
        self._sync_seen = seen

    def _count_sync_drops(self) -> None:
        """Frames the stereo sync dropped since the last call, per side."""
        stats = self.sync.stats
        now = (stats.dropped_left, stats.dropped_right)
        self._count_unpaired(now[0] - self._sync_sides_seen[0],
                             now[1] - self._sync_sides_seen[1])
        self._sync_sides_seen = now

    def _count_unpaired(self, left: int, right: int) -> None:
        if left:
            self._diag.count("sync_unpaired_left", left)
        if right:
            self._diag.count("sync_unpaired_right", right)

    def ledger_gauges(self) -> None:
        """What is still in flight, so the counters reconcile at any moment; and the one loss
        total, ``frames_lost``: images without a partner (``stale_stamp`` ones among them,
        also counted on their own as ``sync_stale``), pairs dropped from the queue and pairs
        that failed."""
        pending = self.sync.pending
        self._diag.gauge("sync_pending_left", pending[0])
        self._diag.gauge("sync_pending_right", pending[1])
        self._diag.gauge("queued", len(self._queue))
        self._diag.gauge("sync_stale", self.sync.stats.dropped_stale)
        self._diag.gauge("frames_lost", sum(self._diag.counter(k) for k in (
            "sync_unpaired_left", "sync_unpaired_right", "dropped_pairs", "failed_pairs")))


class LocatorSource:
    """The locator of the current calibration: from ``calibration_dir``, or from the latest
    ``camera_info`` pair (rebuilt, and warmed up, when it changes).

    Args:
        config: the locator's configuration.
        diag: the node's diagnostics (``no_camera_info``, ``bad_camera_info``).
        calibration_dir: left.yaml + right.yaml (stereo.yaml optional); empty: camera_info.

    Raises:
        ConfigError: ``calibration_dir`` cannot be loaded or gives no usable locator.
    """

    def __init__(self, config: LocatorConfig, diag: Any, calibration_dir: str = "") -> None:
        self._config = config
        self._diag = diag
        self._locator: StereoLocator | None = None
        self.from_files = bool(calibration_dir)
        if self.from_files:
            rig = StereoRig.load(calibration_dir)
            try:
                self._locator = StereoLocator(rig, config)
            except InputError as exc:
                raise ConfigError(f"calibration_dir '{calibration_dir}': {exc}") from exc
            self._locator.warm_up()
        self._info: dict[str, Any] = {"left": None, "right": None}
        self._info_key: tuple[Any, ...] | None = None
        self._lock = threading.Lock()

    def on_info(self, side: str, msg: CameraInfo) -> None:
        """Keep the latest camera_info of ``side`` (executor thread)."""
        with self._lock:
            self._info[side] = msg

    def current(self) -> StereoLocator | None:
        """The locator for the next pair (worker thread); None (reported) when there is no
        usable calibration yet."""
        if self.from_files:
            return self._locator
        with self._lock:
            left, right = self._info["left"], self._info["right"]
        if left is None or right is None:
            missing = [s for s, m in (("left", left), ("right", right)) if m is None]
            self._diag.report("no_camera_info", f"no camera_info received on "
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
                self._locator = StereoLocator(rig, self._config)
                self._locator.warm_up()
            except (ConversionError, ConfigError, InputError) as exc:
                self._locator = None
                self._diag.report("bad_camera_info", f"camera_info: {exc}")
            self._info_key = key
        if self._locator is None:
            self._diag.report("bad_camera_info", "camera_info does not describe a usable "
                              "calibrated stereo pair: pairs are skipped")
        return self._locator


def color_image(msg: Image, topic: str, size: tuple[int, int], diag: Any) -> np.ndarray | None:
    """The image as a contiguous BGR array (``8UC3`` as it is); None (reported on ``diag``)
    for an encoding not in :data:`COLOR_ENCODINGS`, a size other than the calibration's
    ``size`` (width, height) or data that cannot be decoded."""
    if msg.encoding not in COLOR_ENCODINGS:
        diag.report("bad_encoding", f"{topic}: encoding '{msg.encoding}' is not a "
                    f"colour image (accepted: {', '.join(COLOR_ENCODINGS)})")
        return None
    if (msg.width, msg.height) != size:
        diag.report("size_mismatch", f"{topic}: image is {msg.width}x{msg.height} but "
                    f"the calibration is {size[0]}x{size[1]}")
        return None
    try:
        enc = "bgr8" if msg.encoding != "8UC3" else None
        img = image_to_numpy(msg, desired_encoding=enc)
    except ConversionError as exc:
        diag.report("bad_image", f"{topic}: {exc}")
        return None
    return np.ascontiguousarray(img)
