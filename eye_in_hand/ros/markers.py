"""Per-frame target lists for RViz and for other nodes: MarkerArray spheres and PoseArray.

``detect_triangulate`` publishes ``targets/markers`` and ``hand_eye`` ``target/markers``: one
``visualization_msgs/MarkerArray`` per processed frame, stamped with the image stamp, that
starts with a ``DELETEALL`` marker (RViz forgets the spheres of earlier frames, so a target
that left the view does not stay on screen) followed by one ``SPHERE`` marker per located
target with ``ns`` = the target id, ``id`` = 0, ``scale`` = the sphere's diameter and a
``lifetime`` (a display that missed the next frame still drops the sphere). ``hand_eye`` reads
``targets/markers`` as the list of the targets of each frame (:func:`spheres_from_marker_fields`
of its markers' fields, read from the message's bytes or from a message object).

``hand_eye`` also publishes ``target/poses``: a ``geometry_msgs/PoseArray`` of the same frame,
poses in the order of the spheres of ``target/markers``.

Message classes are looked up with :func:`eye_in_hand.ros.msgtypes.import_message_type`, so a
missing ``visualization_msgs`` gives one clear error instead of an ImportError.
"""
from __future__ import annotations

import colorsys
import functools
import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from eye_in_hand.errors import ConfigError, ConversionError
from eye_in_hand.ros.fields import get_field
from eye_in_hand.ros.geometry import header_fields
from eye_in_hand.ros.msgtypes import import_message_type
from eye_in_hand.ros.outputs import DEFAULT_RGBA, Sphere, pose_array, rclpy_types, sphere_markers
from eye_in_hand.ros.stamps import sec_nanosec_to_ns

__all__ = ["Sphere", "marker_classes", "pose_array_class", "sphere_marker_array",
           "spheres_from_marker_array", "spheres_from_marker_fields", "marker_fields",
           "marker_array_fields",
           "points_to_pose_array", "color_range_rgba",
           "sphere_style", "DEFAULT_RGBA"]

@functools.cache
def marker_classes() -> tuple[Any, Any]:
    """``(Marker, MarkerArray)`` of visualization_msgs.

    Raises:
        ConfigError: visualization_msgs is not installed.
    """
    marker = import_message_type("visualization_msgs/msg/Marker")
    array = import_message_type("visualization_msgs/msg/MarkerArray")
    if marker is None or array is None:
        raise ConfigError("visualization_msgs is not installed (it comes with "
                          "ros-jazzy-common-interfaces): no MarkerArray can be published")
    return marker, array


@functools.cache
def pose_array_class() -> Any:
    """``geometry_msgs.msg.PoseArray`` (ConfigError when geometry_msgs is missing)."""
    cls = import_message_type("geometry_msgs/msg/PoseArray")
    if cls is None:
        raise ConfigError("geometry_msgs is not installed: no PoseArray can be published")
    return cls


def color_range_rgba(lower: Sequence[int], upper: Sequence[int], *, wraps: bool | None = None,
                     alpha: float = 0.8) -> tuple[float, float, float, float]:
    """The display colour of an OpenCV HSV/HSI range: its middle hue at full saturation.

    Args:
        lower, upper: (h, s, v) bounds, h in 0..179 (OpenCV's half degrees); a hue range wraps
            around 0 when ``lower[0] > upper[0]`` (red) unless ``wraps`` says otherwise.
        alpha: the opacity.

    Returns:
        (r, g, b, a), each in 0..1.
    """
    lo_h, hi_h = int(lower[0]), int(upper[0])
    wrap = lo_h > hi_h if wraps is None else wraps
    hue = ((lo_h + hi_h + (180 if wrap else 0)) / 2.0) % 180.0
    r, g, b = colorsys.hsv_to_rgb(hue / 180.0, 1.0, 1.0)
    return (float(r), float(g), float(b), float(alpha))


def sphere_marker_array(spheres: Iterable[Sphere], *, stamp_ns: int, frame_id: str,
                        lifetime_s: float = 0.0) -> Any:
    """A MarkerArray: ``DELETEALL``, then one ``SPHERE`` (``ns`` = id, ``id`` 0) per sphere
    (:func:`eye_in_hand.ros.outputs.sphere_markers`, the builder ``process`` writes with).

    Args:
        spheres: the frame's targets (possibly none: the array then only clears the display).
        stamp_ns: the image stamp (int ns), on every marker.
        frame_id: the frame of the centres.
        lifetime_s: how long RViz shows a sphere that no later frame replaced (0 = until
            replaced or deleted).

    Raises:
        ConversionError: a non-finite centre, a diameter that is not positive, or two spheres
            with one id.
    """
    marker_classes()            # one clear error when visualization_msgs is missing
    return sphere_markers(rclpy_types(), spheres, stamp_ns, frame_id, lifetime_s)


def sphere_style(radius_m: float | None, color: Any, default_diameter_m: float
                 ) -> tuple[float, tuple[float, float, float, float]]:
    """Diameter (m) and RGBA of a target's sphere: twice its configured radius (else
    ``default_diameter_m``) and the middle hue of its colour range (else :data:`DEFAULT_RGBA`).
    ``color``: the target's colour range (``lower``, ``upper``, ``wraps``), or None."""
    diameter = 2.0 * radius_m if radius_m else default_diameter_m
    rgba = (color_range_rgba(color.lower, color.upper, wraps=color.wraps)
            if color is not None else DEFAULT_RGBA)
    return float(diameter), rgba


def marker_fields(m: Any) -> tuple[Any, ...]:
    """``(sec, nanosec, frame_id, ns, type, action, (x, y, z), scale_x, (r, g, b, a))`` of a
    ``Marker`` message object (rclpy or rosbags), as ``eye_in_hand.io.cdr.
    marker_array_from_cdr`` reads them from its bytes: what :func:`spheres_from_marker_fields`
    checks.

    Raises:
        ConversionError: a missing field (named).
    """
    p = get_field(get_field(m, "pose", "marker"), "position", "marker.pose")
    c = get_field(m, "color", "marker")
    return (*header_fields(m, "marker"), get_field(m, "ns", "marker"),
            get_field(m, "type", "marker"), get_field(m, "action", "marker"),
            tuple(get_field(p, a, "marker.pose.position") for a in ("x", "y", "z")),
            get_field(get_field(m, "scale", "marker"), "x", "marker.scale"),
            tuple(get_field(c, a, "marker.color") for a in ("r", "g", "b", "a")))


def marker_array_fields(msg: Any) -> list[tuple[Any, ...]]:
    """:func:`marker_fields` of each marker of a MarkerArray message object."""
    return [marker_fields(m) for m in get_field(msg, "markers", "")]


def spheres_from_marker_array(msg: Any) -> tuple[int, str, list[Sphere]]:
    """The frame's targets from a MarkerArray message object written by
    :func:`sphere_marker_array`: :func:`spheres_from_marker_fields` of its markers."""
    return spheres_from_marker_fields(marker_array_fields(msg))


def spheres_from_marker_fields(markers: Sequence[tuple[Any, ...]]
                               ) -> tuple[int, str, list[Sphere]]:
    """The frame's targets from the markers of a MarkerArray (:func:`marker_fields` of each,
    or ``eye_in_hand.io.cdr.marker_array_from_cdr`` of its bytes).

    ``SPHERE`` markers with action ``ADD`` are targets; ``DELETEALL`` / ``DELETE`` markers are
    skipped; any other marker is an error.

    Returns:
        ``(stamp_ns, frame_id, spheres)``: the stamp and frame of the markers (the array's own
        stamp when it holds only a DELETEALL), and the spheres in message order.

    Raises:
        ConversionError: no marker at all, markers of one array with different stamps or
            frames, an empty or repeated ``ns``, a non-finite centre or a scale that is not
            positive (the message names the marker).
    """
    if not markers:
        raise ConversionError("markers: empty MarkerArray (expected at least a DELETEALL)")
    sec, nanosec, frame = markers[0][:3]
    stamp = sec_nanosec_to_ns(sec, nanosec, "markers[0].header.stamp")
    spheres: list[Sphere] = []
    seen: set[str] = set()
    for k, (sec, nanosec, m_frame, ns, mtype, action, position, d, rgba) in enumerate(markers):
        where = f"markers[{k}] (ns '{ns}')"
        if sec_nanosec_to_ns(sec, nanosec, f"markers[{k}].header.stamp") != stamp \
                or m_frame != frame:
            raise ConversionError(f"{where}: stamp or frame differs from markers[0]'s")
        if action in (2, 3):          # DELETE, DELETEALL
            continue
        if action != 0 or mtype != 2:   # ADD, SPHERE
            raise ConversionError(f"{where}: expected SPHERE/ADD, got type {mtype} action "
                                  f"{action}")
        if not ns or ns in seen:
            raise ConversionError(f"{where}: the target id (ns) is empty or repeated")
        seen.add(ns)
        xyz = np.array(position, dtype=np.float64)
        if not np.isfinite(xyz).all():
            raise ConversionError(f"{where}: position is not finite")
        d = float(d)
        if not (math.isfinite(d) and d > 0):
            raise ConversionError(f"{where}: scale.x must be > 0, got {d}")
        spheres.append(Sphere(ns, xyz, d, (float(rgba[0]), float(rgba[1]), float(rgba[2]),
                                           float(rgba[3]))))
    return stamp, frame, spheres


def points_to_pose_array(points: Iterable[np.ndarray], *, stamp_ns: int, frame_id: str) -> Any:
    """A PoseArray with one pose per point (position = the point, orientation identity;
    :func:`eye_in_hand.ros.outputs.pose_array`).

    Args:
        points: shapes (3,), metres.
        stamp_ns: the image stamp (int ns).
        frame_id: the frame of the points.

    Raises:
        ConversionError: a point is not 3 finite numbers.
    """
    pose_array_class()          # one clear error when geometry_msgs is missing
    return pose_array(rclpy_types(), points, stamp_ns, frame_id)
