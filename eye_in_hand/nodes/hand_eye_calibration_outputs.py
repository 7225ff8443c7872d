"""The ``hand_eye`` node's calibration-mode topics: status, next poses, the debug image.

:class:`CalibrationOutputs` is a part of the calibration mode
(:class:`eye_in_hand.nodes.hand_eye_calibration.CalibrationMode`), built with explicit
arguments: ``~/calibration_status`` (CalibrationStatus, latched, when eye_in_hand_interfaces
is built), ``~/next_poses`` (PoseArray of the suggested flange poses, latched),
``~/next_pose_markers`` (MarkerArray) and ``~/debug_image`` (the board drawn on the left
image by :func:`eye_in_hand.report.board_image.board_debug_image` on a worker thread, only
while someone subscribes, at most ``debug_image_rate_hz``).
"""
from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseArray
from sensor_msgs.msg import Image

from eye_in_hand.core.handeye import HandEyeResult
from eye_in_hand.core.handeye.session import SessionStatus
from eye_in_hand.report.board_image import board_debug_image
from eye_in_hand.ros.handeye_msgs import (
    have_interfaces,
    iface_msg,
    next_pose_markers,
    pose_array,
    status_message,
)
from eye_in_hand.ros.handoff import WorkerHandoff
from eye_in_hand.ros.images import image_to_numpy, numpy_to_image
from eye_in_hand.ros.markers import marker_classes
from eye_in_hand.ros.qos import LATCHED_QOS, RESULT_QOS

__all__ = ["CalibrationOutputs"]


class CalibrationOutputs:
    """The calibration mode's published topics (see the module docstring).

    Args:
        node: the rclpy node (publishers, clock, log).
        config: the node's configuration (``setup``, ``base_frame``, ``ee_frame``,
            ``debug_image_rate_hz``).
        diag: the node's diagnostics (gauges ``good_enough``, ``problems``; cause
            ``debug_image``).
        board: the calibration board (:class:`eye_in_hand.core.calibration.BoardSpec`).
        views: the rig's cameras (the first one's images are drawn on).
        handoff: the calibration mode's worker threads (pool ``debug`` draws).
    """

    def __init__(self, node: Any, config: Any, diag: Any, board: Any, views: Sequence[Any],
                 handoff: WorkerHandoff) -> None:
        self._clock = node.get_clock()
        self.config = config
        self.diag = diag
        self.board = board
        self.views = list(views)
        self._handoff = handoff
        self._debug_busy = False
        self._debug_last = 0.0
        if have_interfaces():
            self.pub_status = node.create_publisher(iface_msg.CalibrationStatus,
                                                    "~/calibration_status", LATCHED_QOS)
        else:
            self.pub_status = None
            node.get_logger().warning(
                "eye_in_hand_interfaces is not installed: only the std_srvs/Trigger services "
                "(hand_eye/capture, compute, save, reset) are offered (run 'make venv')")
        self.pub_next = node.create_publisher(PoseArray, "~/next_poses", LATCHED_QOS)
        self.pub_markers = node.create_publisher(marker_classes()[1], "~/next_pose_markers",
                                                 LATCHED_QOS)
        self.pub_debug = node.create_publisher(Image, "~/debug_image", RESULT_QOS)

    def pose_array(self, poses: Sequence[np.ndarray]) -> PoseArray:
        """The suggested flange poses in ``base_frame``, stamped now."""
        return pose_array(poses, self._clock.now().to_msg(), self.config.base_frame)

    def status_message(self, st: SessionStatus,
                       loaded: tuple[np.ndarray, np.ndarray | None, str] | None) -> Any:
        """CalibrationStatus of ``st`` (with a loaded calibration's X when ``st`` has no
        estimate), stamped now."""
        return status_message(st, self._clock.now().to_msg(), loaded,
                              self.pose_array(st.suggestions))

    def publish_status(self, st: SessionStatus,
                       loaded: tuple[np.ndarray, np.ndarray | None, str] | None) -> None:
        """``~/calibration_status`` (when the interfaces exist) and the diagnostics gauges."""
        if self.pub_status is not None:
            self.pub_status.publish(self.status_message(st, loaded))
        self.diag.gauge("good_enough", bool(st.good_enough))
        self.diag.gauge("problems", "; ".join(st.problems))

    def publish_next(self, suggestions: Sequence[np.ndarray],
                     estimate: HandEyeResult | None) -> None:
        """``~/next_poses`` and ``~/next_pose_markers`` (the board where ``estimate`` puts
        it: in the base frame eye-in-hand, the flange frame eye-to-hand)."""
        arr = self.pose_array(suggestions)
        self.pub_next.publish(arr)
        cfg = self.config
        board_pose = None if estimate is None else estimate.methods[estimate.selected].Y
        board_frame = cfg.ee_frame if cfg.setup == "eye_to_hand" else cfg.base_frame
        self.pub_markers.publish(next_pose_markers(arr, self.board, board_pose, board_frame))

    def debug_image(self, stamp: int, frame: dict[str, Image], n_samples: int) -> None:
        """Draw the board on the frame's first image on the worker, when someone subscribes
        to ``~/debug_image`` and the rate allows (one drawing at a time)."""
        rate = self.config.debug_image_rate_hz
        now = time.monotonic()
        if (rate <= 0 or self._debug_busy or now - self._debug_last < 1.0 / rate
                or self.pub_debug.get_subscription_count() == 0):
            return
        self._debug_busy, self._debug_last = True, now
        msg = frame[self.views[0].name]
        self._handoff.submit("debug", lambda: self._draw_debug(stamp, msg, n_samples))

    def _draw_debug(self, stamp: int, msg: Image, n_samples: int) -> None:
        try:
            img = image_to_numpy(msg, desired_encoding="bgr8")
            out = board_debug_image(img, self.board, self.views[0].model, n_samples)
            self.pub_debug.publish(numpy_to_image(out, "bgr8", stamp_ns=stamp,
                                                  frame_id=msg.header.frame_id))
        except Exception as exc:  # noqa: BLE001 - a debug image must never stop the node
            self.diag.report("debug_image", f"debug image: {exc}")
        finally:
            self._debug_busy = False
