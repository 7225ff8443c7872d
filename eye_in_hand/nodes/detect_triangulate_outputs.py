"""The ``detect_triangulate`` node's outputs: the located targets' topics and the debug image.

:class:`TargetPublishers` is a part of
:class:`eye_in_hand.nodes.detect_triangulate.DetectTriangulateNode` (an object with explicit
constructor arguments): it makes the node's output publishers and sends what the locator found
in one stereo pair: ``target/point_cov`` and ``target/point`` (the first target),
``targets/<id>/point_cov`` and ``targets/<id>/point`` (every target; publishers made when an id
first appears, at most ``max_targets``), ``targets/markers`` (the frame's list of targets) and,
rate-limited, ``target/debug_image``. Messages are the bytes of :mod:`eye_in_hand.ros.outputs`'
messages, as ``process`` builds them, serialized by :mod:`eye_in_hand.ros.outputs_cdr`.
"""
from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from geometry_msgs.msg import PointStamped, PoseWithCovarianceStamped
from sensor_msgs.msg import Image

from eye_in_hand.core.debug_image import draw_located_pair
from eye_in_hand.core.detection import TargetSpec
from eye_in_hand.core.locator import LocateResult, TargetLocation
from eye_in_hand.ros.images import numpy_to_image
from eye_in_hand.ros.markers import Sphere, marker_classes, sphere_style
from eye_in_hand.ros.names import topic_name_problem
from eye_in_hand.ros.outputs_cdr import point_cdr, sphere_markers_cdr
from eye_in_hand.ros.qos import RESULT_QOS, SENSOR_QOS, TARGET_POINT_QOS

__all__ = ["TargetPublishers"]


class TargetPublishers:
    """The located targets' topics of the ``detect_triangulate`` node, and its debug image.

    Args:
        create: the node's output publisher factory (``OutputPublishers.create``).
        diag: the node's diagnostics (the every-target counters, refused ids).
        targets_prefix: the resolved namespace of ``targets/markers``: ``targets/<id>/...``
            live next to it, wherever a remapping put it.
        targets: the configured targets: their names get publishers now; their radius and
            colour give the spheres on ``targets/markers``.
        max_targets: most ids with ``targets/<id>/...`` publishers.
        marker_lifetime_s: lifetime of the spheres on ``targets/markers`` (0: until the next
            frame's DELETEALL).
        marker_diameter_m: sphere diameter of a target of unknown radius.
        debug_rate_hz: rate limit of ``target/debug_image`` (0: never).
    """

    def __init__(self, create: Callable[..., Any], diag: Any, targets_prefix: str,
                 targets: Sequence[TargetSpec], *, max_targets: int, marker_lifetime_s: float,
                 marker_diameter_m: float, debug_rate_hz: float) -> None:
        self._create = create
        self._diag = diag
        self._prefix = targets_prefix
        self.pub_point = create(PointStamped, "target/point", RESULT_QOS)
        self.pub_point_cov = create(PoseWithCovarianceStamped, "target/point_cov", RESULT_QOS)
        self.pub_markers = create(marker_classes()[1], "targets/markers", RESULT_QOS)
        self.pub_debug = create(Image, "target/debug_image", SENSOR_QOS)
        # per-target publishers, by target id: the configured names now, others when they
        # first appear (worker thread), at most max_targets ids
        self._max_targets = int(max_targets)
        self.per_target: dict[str, tuple[Any, Any]] = {}
        self._lock = threading.Lock()
        self._marker_lifetime_s = float(marker_lifetime_s)
        self._marker_diameter_m = float(marker_diameter_m)
        self._specs = {t.name: t for t in targets}
        self._styles: dict[str, tuple[float, tuple[float, float, float, float]]] = {}
        self._debug_period = 1.0 / debug_rate_hz if debug_rate_hz > 0 else math.inf
        self.last_debug = -math.inf
        for t in targets:
            self._target_publishers(t.name)

    @property
    def target_ids(self) -> list[str]:
        """The target ids that have publishers (the configured names from the start)."""
        with self._lock:
            return list(self.per_target)

    def publish(self, result: LocateResult, stamp: int, frame: str
                ) -> list[tuple[Sphere, np.ndarray]]:
        """The first target on ``target/point_cov`` and ``target/point`` (when found), then
        every target (:meth:`publish_targets`); returns what that returns."""
        first = result.first
        first_msgs = None
        if first is not None:
            # The covariance first: hand_eye pairs the two by stamp and waits for the point.
            # The same two messages go to targets/<first id>/... below (built once).
            first_msgs = self._messages(first, stamp, frame)
            # volatile topics: a message nobody subscribes to reaches no one, now or later
            # (as in hand_eye); the transient-local targets/<id>/... below always go out
            if self.pub_point_cov.get_subscription_count() > 0:
                self.pub_point_cov.publish(first_msgs[0])
            if self.pub_point.get_subscription_count() > 0:
                self.pub_point.publish(first_msgs[1])
        return self.publish_targets(result, stamp, frame, first_msgs)

    @staticmethod
    def _messages(t: TargetLocation, stamp: int, frame: str) -> tuple[bytes, bytes]:
        """``(point_cov, point)`` of a located target, serialized: a PoseWithCovarianceStamped
        (position the point, covariance position block the triangulation covariance,
        orientation variances 1e6) and a PointStamped, as ``process`` writes them
        (:func:`eye_in_hand.ros.outputs_cdr.point_cdr`)."""
        return point_cdr(t.point_m, t.covariance, stamp, frame)

    def _target_publishers(self, tid: str) -> tuple[Any, Any] | None:
        """``(point, point_cov)`` publishers of ``targets/<tid>/...``, made on first use; None
        (reported) when ``tid`` is no valid topic token or ``max_targets`` ids have some."""
        with self._lock:
            pubs = self.per_target.get(tid)
            if pubs is not None:
                return pubs
            problem = topic_name_problem(f"targets/{tid}/point") if tid and "/" not in tid \
                else "empty or contains '/'"
            if problem is not None:
                self._diag.report("bad_target_id", f"target id {tid!r} cannot name a topic "
                                  f"({problem}): not published")
                return None
            if len(self.per_target) >= self._max_targets:
                self._diag.report("too_many_targets", f"target id {tid!r}: {self._max_targets} "
                                  "ids have publishers already (max_targets): not published")
                return None
            base = f"{self._prefix}/{tid}"
            pubs = (self._create(PointStamped, f"{base}/point", TARGET_POINT_QOS),
                    self._create(PoseWithCovarianceStamped, f"{base}/point_cov",
                                 TARGET_POINT_QOS))
            self.per_target[tid] = pubs
            return pubs

    def publish_targets(self, result: LocateResult, stamp: int, frame: str,
                        first_msgs: tuple[bytes, bytes] | None = None
                        ) -> list[tuple[Sphere, np.ndarray]]:
        """Every located target on its own topics, then the frame's ``targets/markers``.
        ``first_msgs``: the ``(point_cov, point)`` messages already built for
        ``result.first`` (``target/point_cov``, ``target/point``), sent again as they are.
        Returns each published target's sphere (as on ``targets/markers``) and covariance."""
        spheres = []
        delivered = []
        for t in result.targets:
            self._diag.count("targets_located")
            pubs = self._target_publishers(t.id)
            if pubs is None:
                self._diag.count("targets_refused")
                continue
            if first_msgs is not None and t is result.first:
                cov_msg, point_msg = first_msgs
            else:
                cov_msg, point_msg = self._messages(t, stamp, frame)
            pubs[1].publish(cov_msg)
            pubs[0].publish(point_msg)
            self._diag.count("target_points_published")
            diameter, rgba = self._sphere_style(t.name)
            spheres.append(Sphere(t.id, t.point_m, diameter, rgba))
            delivered.append((spheres[-1], t.covariance))
        if self.pub_markers.get_subscription_count() > 0:     # volatile, as above
            self.pub_markers.publish(sphere_markers_cdr(spheres, stamp, frame,
                                                        self._marker_lifetime_s))
        self._diag.count("marker_frames")
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

    def publish_debug(self, left: np.ndarray, right: np.ndarray, result: LocateResult,
                      stamp: int, frame_id: str) -> None:
        """``target/debug_image``: only while someone subscribes, at most at the rate limit."""
        now = time.monotonic()
        if now - self.last_debug < self._debug_period or \
                self.pub_debug.get_subscription_count() == 0:
            return
        self.last_debug = now
        canvas = draw_located_pair(left, right, result)
        self.pub_debug.publish(numpy_to_image(canvas, "bgr8", stamp_ns=stamp,
                                              frame_id=frame_id))
