"""The live outputs of :mod:`eye_in_hand.ros.outputs`, serialized directly (CDR bytes).

``hand_eye`` sends about seven messages per stereo pair, ``detect_triangulate`` five. Built
as rclpy objects, each costs its nested ``__init__``s (a ``MarkerArray`` of two markers about
25 us, a pose and its covariance pose 17 us) and rclpy's conversion and serialization at
``publish`` (5-20 us). The functions here write the same messages' CDR bytes with ``struct``
(a few us each), and the node publishes the bytes (``Publisher.publish(bytes)``: rclpy hands
them to the middleware as they are). ``process`` writes the same bytes into its output bag
(:mod:`eye_in_hand.io.results`): building the rosbags objects and serializing them cost
about 0.4 ms a frame.

The content rules are :mod:`eye_in_hand.ros.outputs`'s, used from there: the checks of points,
stamps and spheres, the covariance of a point published as a pose, the sphere markers' type,
actions and lifetime. ``test/ros/test_outputs_cdr.py`` holds every function here to the
bytes rosbags serializes of the builder's message (padding zeroed, as rosbags writes it) for
a range of inputs, so the two cannot drift apart.

Plain little-endian CDR (encapsulation ``00 01 00 00``), what every ROS 2 middleware reads;
alignment counts from the end of the 4-byte encapsulation header.
"""
from __future__ import annotations

import functools
import struct
from collections.abc import Iterable
from typing import Any

from eye_in_hand.core.transforms import value_key
from eye_in_hand.ros.outputs import (
    MARKER_ADD,
    MARKER_DELETEALL,
    MARKER_SPHERE,
    Sphere,
    checked_frame,
    checked_spheres,
    checked_xyz,
    marker_lifetime_ns,
    point_pose_covariance,
    stamp_parts,
)

__all__ = ["point_cdr", "point_stamped_cdr", "point_pose_cdr", "LastPointPose",
           "pose_array_cdr", "sphere_markers_cdr", "translation_tf_cdr"]

_ENCAPSULATION = b"\x00\x01\x00\x00"
_U32 = struct.Struct("<I")
_STAMP = struct.Struct("<iI")
_POSE = struct.Struct("<7d")                 # position xyz, orientation xyzw
_XYZ = struct.Struct("<3d")
_SPHERE_TAIL = struct.Struct("<3i")          # id, type, action
_SCALE_COLOR_LIFE = struct.Struct("<3d4fiI?")


@functools.lru_cache(maxsize=1024)
def _string(text: str) -> bytes:
    """A CDR string from a 4-aligned offset: its length with the terminating NUL, its UTF-8
    bytes, the NUL. Kept per text: a run writes the same frame ids and target ids again and
    again."""
    data = text.encode()
    return _U32.pack(len(data) + 1) + data + b"\x00"


class _Writer:
    """CDR bytes after the encapsulation header; offsets count from the payload's start."""

    __slots__ = ("buf",)

    def __init__(self) -> None:
        self.buf = bytearray(_ENCAPSULATION)

    def align(self, n: int) -> None:
        pad = -(len(self.buf) - 4) % n
        if pad:
            self.buf += bytes(pad)

    def u32(self, value: int) -> None:
        self.align(4)
        self.buf += _U32.pack(value)

    def string(self, text: str) -> None:
        self.align(4)
        self.buf += _string(text)

    def header(self, stamp: tuple[int, int], frame_id: str) -> None:
        self.align(4)
        self.buf += _STAMP.pack(*stamp)
        self.buf += _string(frame_id)     # 4-aligned still: after 8 bytes of stamp

    def pose(self, xyz: tuple[float, float, float]) -> None:
        """A pose at ``xyz`` with the identity orientation."""
        self.align(8)
        self.buf += _POSE.pack(xyz[0], xyz[1], xyz[2], 0.0, 0.0, 0.0, 1.0)


def point_pose_cdr(xyz: Any, cov: Any, stamp_ns: int, frame_id: str) -> tuple[bytes, bytes]:
    """``geometry_msgs/PoseStamped`` and ``PoseWithCovarianceStamped`` of a located point:
    the bytes of :func:`eye_in_hand.ros.outputs.point_pose_messages`.

    Raises:
        ConversionError: the point is not finite, or a bad stamp or frame.
    """
    p = checked_xyz(xyz, "point")
    stamp, frame = stamp_parts(stamp_ns), checked_frame(frame_id)
    pose = _Writer()
    pose.header(stamp, frame)
    pose.pose(p)
    return bytes(pose.buf), _pose_with_covariance(p, cov, stamp, frame)


class LastPointPose:
    """:func:`point_pose_cdr` that keeps its last answer, for a sender of one located point
    on two topic pairs: ``hand_eye`` sends its first target on ``target/pose(_cov)`` and
    again on ``target/<id>/pose(_cov)``, the same bytes. Keyed by value (the stamp, the frame,
    and the point's and covariance's shapes and float64 bytes), so an equal call gets the
    bytes the last one built, whatever arrays it passes; any other call builds and keeps its
    own. One sender's thread (not locked)."""

    __slots__ = ("_key", "_msgs")

    def __init__(self) -> None:
        self._key: tuple[Any, ...] | None = None
        self._msgs = (b"", b"")

    def __call__(self, xyz: Any, cov: Any, stamp_ns: int, frame_id: str
                 ) -> tuple[bytes, bytes]:
        """:func:`point_pose_cdr` ``(xyz, cov, stamp_ns, frame_id)``: the same bytes."""
        try:
            key = (stamp_ns, frame_id, value_key(xyz), value_key(cov))
        except (TypeError, ValueError):
            return point_pose_cdr(xyz, cov, stamp_ns, frame_id)   # its own error
        if key != self._key:
            self._msgs = point_pose_cdr(xyz, cov, stamp_ns, frame_id)
            self._key = key
        return self._msgs


def _pose_with_covariance(p: tuple[float, float, float], cov: Any, stamp: tuple[int, int],
                          frame: str) -> bytes:
    w = _Writer()
    w.header(stamp, frame)
    w.pose(p)
    w.buf += point_pose_covariance(cov).astype("<f8").tobytes()
    return bytes(w.buf)


def point_cdr(xyz: Any, cov: Any, stamp_ns: int, frame_id: str) -> tuple[bytes, bytes]:
    """``geometry_msgs/PoseWithCovarianceStamped`` and ``PointStamped`` of a located point in
    the camera frame (``target/point_cov``, ``target/point``): the bytes of
    :func:`eye_in_hand.ros.outputs.pose_with_covariance` and
    :func:`eye_in_hand.ros.outputs.point_stamped`.

    Raises:
        ConversionError: the point is not finite, or a bad stamp or frame.
    """
    p = checked_xyz(xyz, "point")
    stamp, frame = stamp_parts(stamp_ns), checked_frame(frame_id)
    return _pose_with_covariance(p, cov, stamp, frame), _point_stamped(p, stamp, frame)


def _point_stamped(p: tuple[float, float, float], stamp: tuple[int, int], frame: str) -> bytes:
    w = _Writer()
    w.header(stamp, frame)
    w.align(8)
    w.buf += _XYZ.pack(*p)
    return bytes(w.buf)


def point_stamped_cdr(xyz: Any, stamp_ns: int, frame_id: str) -> bytes:
    """``geometry_msgs/PointStamped``: the bytes of
    :func:`eye_in_hand.ros.outputs.point_stamped`.

    Raises:
        ConversionError: the point is not finite, or a bad stamp or frame.
    """
    return _point_stamped(checked_xyz(xyz, "point"), stamp_parts(stamp_ns),
                          checked_frame(frame_id))


def pose_array_cdr(points: Iterable[Any], stamp_ns: int, frame_id: str) -> bytes:
    """``geometry_msgs/PoseArray``: the bytes of :func:`eye_in_hand.ros.outputs.pose_array`.

    Raises:
        ConversionError: a point is not 3 finite numbers.
    """
    checked = [checked_xyz(p, f"points[{k}]") for k, p in enumerate(points)]
    w = _Writer()
    w.header(stamp_parts(stamp_ns), checked_frame(frame_id))
    w.u32(len(checked))
    for p in checked:
        w.pose(p)
    return bytes(w.buf)


def _marker(w: _Writer, stamp: tuple[int, int], frame: str, ns: str, kind: int, action: int,
            xyz: tuple[float, float, float], diameter: float,
            rgba: tuple[float, float, float, float], life: tuple[int, int]) -> None:
    """One ``visualization_msgs/Marker``: the given fields, every other one its default."""
    w.header(stamp, frame)
    w.string(ns)
    w.align(4)
    w.buf += _SPHERE_TAIL.pack(0, kind, action)
    w.pose(xyz)
    w.buf += _SCALE_COLOR_LIFE.pack(diameter, diameter, diameter, *rgba, *life, False)
    w.buf += _MARKER_TAILS[(len(w.buf) - 4) % 4]


def _marker_tail(offset: int) -> bytes:
    """The fields of a ``Marker`` after its lifetime, all empty, written at a payload offset
    ``offset`` (mod 4: they align to 4 bytes at most, so four variants are all there is)."""
    w = _Writer()
    w.buf += bytes(offset)
    start = len(w.buf)
    w.u32(0)                          # points
    w.u32(0)                          # colors
    w.string("")                      # texture_resource
    w.header((0, 0), "")              # texture: sensor_msgs/CompressedImage
    w.string("")                      #   format
    w.u32(0)                          #   data
    w.u32(0)                          # uv_coordinates
    w.string("")                      # text
    w.string("")                      # mesh_resource
    w.string("")                      # mesh_file: filename
    w.u32(0)                          #   data
    w.buf += b"\x00"                  # mesh_use_embedded_materials
    return bytes(w.buf[start:])


#: :func:`_marker_tail` after a payload of each length mod 4 (13 small writes per marker
#: otherwise: about 5 us of a marker's 10)
_MARKER_TAILS = tuple(_marker_tail(r) for r in range(4))


def sphere_markers_cdr(spheres: Iterable[Sphere], stamp_ns: int, frame_id: str,
                       lifetime_s: float = 0.0) -> bytes:
    """``visualization_msgs/MarkerArray`` of ``DELETEALL`` and one ``SPHERE`` per sphere: the
    bytes of :func:`eye_in_hand.ros.outputs.sphere_markers`.

    Raises:
        ConversionError: a non-finite centre, a diameter that is not positive, two spheres
            with one id, a colour that is not 4 finite float32 values, or a lifetime that
            does not fit a Duration.
    """
    checked = list(checked_spheres(spheres))
    stamp, frame = stamp_parts(stamp_ns), checked_frame(frame_id)
    life = divmod(marker_lifetime_ns(lifetime_s), 1_000_000_000)
    w = _Writer()
    w.u32(1 + len(checked))
    _marker(w, stamp, frame, "", 0, MARKER_DELETEALL, (0.0, 0.0, 0.0), 0.0,
            (0.0, 0.0, 0.0, 0.0), (0, 0))
    for s, xyz in checked:
        rgba = (float(s.rgba[0]), float(s.rgba[1]), float(s.rgba[2]), float(s.rgba[3]))
        _marker(w, stamp, frame, s.id, MARKER_SPHERE, MARKER_ADD, xyz, float(s.diameter_m),
                rgba, (int(life[0]), int(life[1])))
    return bytes(w.buf)


def translation_tf_cdr(edges: Iterable[tuple[str, str, int, Any]]) -> bytes:
    """``tf2_msgs/TFMessage`` of translation-only transforms ``(parent, child, stamp_ns,
    translation (3,))``: the bytes of :func:`eye_in_hand.ros.outputs.translation_tf_message`.

    Raises:
        ConversionError: a translation is not 3 finite numbers, or a bad stamp or frame.
    """
    checked = [(stamp_parts(int(stamp)), checked_frame(parent), checked_frame(child),
                checked_xyz(t, f"translation of {parent} -> {child}"))
               for parent, child, stamp, t in edges]
    w = _Writer()
    w.u32(len(checked))
    for stamp, parent, child, p in checked:
        w.header(stamp, parent)
        w.string(child)
        w.pose(p)
    return bytes(w.buf)
