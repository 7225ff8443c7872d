"""Direct CDR decoding of ``sensor_msgs/msg/Image`` (the pixels as a view, never copied), of
``geometry_msgs/msg/PoseStamped`` (a robot pose stream's fields without a message object) and
of what ``hand_eye`` reads from a detector each stereo pair (``geometry_msgs/msg/PointStamped``,
``geometry_msgs/msg/PoseWithCovarianceStamped``, the spheres of a
``visualization_msgs/msg/MarkerArray``).

A generic CDR deserializer (``rosbags``) builds a message object and copies the pixel sequence
into a new array: ~1 ms per 1280x720 colour image here, a quarter of reading a bag. An image's
layout is fixed, so :func:`image_from_cdr` reads its few scalar fields and returns the pixel
bytes as a numpy view of the buffer it was given (a memory-mapped bag, a decompressed chunk).
A robot that publishes its pose at 125 Hz - 1 kHz sends 4-33 ``PoseStamped`` a stereo pair;
:func:`pose_stamped_from_cdr` reads one's stamp, frame and seven numbers with two ``struct``
calls (1 us) where the generic deserializer builds six nested objects (3-5 us). The
detector's messages of one pair (a point, two points with covariance, one MarkerArray) take
35 us through the generic deserializer, most of it the MarkerArray (25 us for a DELETEALL
and one sphere, every field of both markers built); :func:`point_stamped_from_cdr`,
:func:`pose_cov_stamped_from_cdr` and :func:`marker_array_from_cdr` read the fields the node
uses and step over the others; each refuses what rosbags refuses (a cut, a string without
its NUL or not UTF-8, more than 3 bytes after the last field).

Only little-endian plain CDR (encapsulation ``00 01``, what every ROS 2 middleware writes) is
decoded here; for anything else it returns None and the caller uses the generic deserializer.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from eye_in_hand.errors import ConversionError

__all__ = ["CdrStamp", "CdrHeader", "CdrImage", "image_from_cdr", "is_image_type",
           "pose_stamped_from_cdr", "point_stamped_from_cdr", "pose_cov_stamped_from_cdr",
           "marker_array_from_cdr", "MarkerFields"]

_U32 = struct.Struct("<I")
_STAMP = struct.Struct("<iI")
_HW = struct.Struct("<II")
_POSE = struct.Struct("<7d")
_POINT = struct.Struct("<3d")
_POSE_COV = struct.Struct("<43d")          # Pose (7) and covariance (36)
_I3 = struct.Struct("<3i")                 # a marker's id, type, action
_MARKER_POSE_SCALE = struct.Struct("<10d")  # a marker's pose (7) and scale (3)
_RGBA = struct.Struct("<4f")
#: ``(sec, nanosec, frame_id, ns, type, action, (x, y, z), scale_x, (r, g, b, a))`` of one
#: marker: what :func:`eye_in_hand.ros.markers.spheres_from_marker_fields` reads
MarkerFields = tuple[int, int, str, str, int, int, tuple[float, float, float], float,
                     tuple[float, float, float, float]]
_CDR_LE = b"\x00\x01"


@dataclass(frozen=True)
class CdrStamp:
    sec: int
    nanosec: int


@dataclass(frozen=True)
class CdrHeader:
    stamp: CdrStamp
    frame_id: str


@dataclass(frozen=True)
class CdrImage:
    """The fields of ``sensor_msgs/msg/Image``, with ``data`` a read-only ``uint8`` view."""

    header: CdrHeader
    height: int
    width: int
    encoding: str
    is_bigendian: int
    step: int
    data: np.ndarray


def _string(buf: memoryview, pos: int, field: str) -> tuple[str, int]:
    pos = (pos + 3) & ~3
    if pos + 4 > len(buf):
        raise ConversionError(f"{field}: message ends before the string length")
    (n,) = _U32.unpack_from(buf, pos)
    if n == 0:
        raise ConversionError(f"{field}: string length 0 (a CDR string holds at least its NUL)")
    if pos + 4 + n > len(buf):
        raise ConversionError(f"{field}: string of {n} bytes does not fit the message")
    if n == 1 and buf[pos + 4] == 0:     # empty: most of a marker's strings
        return "", pos + 5
    raw = bytes(buf[pos + 4:pos + 4 + n])
    if raw[-1:] != b"\x00":
        raise ConversionError(f"{field}: string is not NUL-terminated")
    try:
        return raw[:-1].decode(), pos + 4 + n
    except UnicodeDecodeError as exc:
        raise ConversionError(f"{field}: not UTF-8 ({exc})") from exc


def _body(raw: bytes | bytearray | memoryview) -> memoryview | None:
    """The bytes after the 4-byte encapsulation header (CDR alignment counts from their
    start); None when ``raw`` is not little-endian plain CDR."""
    view = memoryview(raw).cast("B") if not isinstance(raw, memoryview) or raw.format != "B" \
        else raw
    if len(view) < 4 or bytes(view[:2]) != _CDR_LE:
        return None
    return view[4:]


def _header(raw: bytes | bytearray | memoryview
            ) -> tuple[memoryview, int, int, str, int] | None:
    """The ``std_msgs/Header`` a message starts with: ``(body, sec, nanosec, frame_id, pos)``,
    ``body`` the bytes after the encapsulation header (CDR alignment counts from its start) and
    ``pos`` the offset in it after the frame id; None when ``raw`` is not little-endian plain
    CDR.

    Raises:
        ConversionError: the message ends inside the header, or a malformed frame id.
    """
    body = _body(raw)
    if body is None:
        return None
    if len(body) < 12:
        raise ConversionError("header: message ends inside header.stamp")
    sec, nanosec = _STAMP.unpack_from(body, 0)
    frame_id, pos = _string(body, 8, "header.frame_id")
    return body, sec, nanosec, frame_id, pos


def image_from_cdr(raw: bytes | bytearray | memoryview) -> CdrImage | None:
    """Decode a serialized ``sensor_msgs/msg/Image`` (with its 4-byte encapsulation header).

    Returns:
        The image, ``data`` a view of ``raw`` (``height * step`` bytes, checked by
        :func:`eye_in_hand.ros.images.image_to_numpy`); None when ``raw`` is not
        little-endian plain CDR.

    Raises:
        ConversionError: a truncated or malformed message (names the field).
    """
    head = _header(raw)
    if head is None:
        return None
    body, sec, nanosec, frame_id, pos = head
    pos = (pos + 3) & ~3
    if pos + 8 > len(body):
        raise ConversionError("height/width: message ends before them")
    height, width = _HW.unpack_from(body, pos)
    encoding, pos = _string(body, pos + 8, "encoding")
    if pos + 1 > len(body):
        raise ConversionError("is_bigendian: message ends before it")
    bigendian = body[pos]
    pos = (pos + 1 + 3) & ~3
    if pos + 8 > len(body):
        raise ConversionError("step: message ends before step and the data length")
    step, n = _HW.unpack_from(body, pos)
    pos += 8
    if pos + n > len(body):
        raise ConversionError(f"data: {n} bytes announced, {len(body) - pos} in the message")
    data = np.frombuffer(body, dtype=np.uint8, count=n, offset=pos)
    if data.flags.writeable:
        data.flags.writeable = False
    return CdrImage(CdrHeader(CdrStamp(sec, nanosec), frame_id), height, width, encoding,
                    bigendian, step, data)


def is_image_type(msgtype: str) -> bool:
    """Whether :func:`image_from_cdr` decodes messages of ``msgtype``."""
    return msgtype == "sensor_msgs/msg/Image"


def pose_stamped_from_cdr(raw: bytes | bytearray | memoryview
                          ) -> tuple[int, int, str, tuple[float, ...]] | None:
    """Decode a serialized ``geometry_msgs/msg/PoseStamped`` (with its encapsulation header).

    Returns:
        ``(sec, nanosec, frame_id, (x, y, z, qx, qy, qz, qw))``: ``header.stamp``,
        ``header.frame_id``, ``pose.position`` and ``pose.orientation`` as they are in the
        message (nothing checked beyond the bytes: the caller checks the values); None when
        ``raw`` is not little-endian plain CDR.

    Raises:
        ConversionError: a truncated or malformed message (names the field).
    """
    return _stamped_doubles(raw, _POSE, "pose")


def _ends_at(body: memoryview, pos: int, what: str) -> None:
    """The message must end at ``pos`` (up to 3 bytes of padding after it, as rosbags
    allows): more is another message's layout (a wrong count, another type)."""
    if len(body) - pos > 3:
        raise ConversionError(f"{what}: {len(body) - pos} bytes after its last field")


def _stamped_doubles(raw: bytes | bytearray | memoryview, fmt: struct.Struct, field: str
                     ) -> tuple[int, int, str, tuple[float, ...]] | None:
    """A message of a header and ``fmt``'s float64 values (8-byte aligned after the frame id,
    the message's end): ``(sec, nanosec, frame_id, values)``; None when ``raw`` is not
    little-endian plain CDR."""
    head = _header(raw)
    if head is None:
        return None
    body, sec, nanosec, frame_id, pos = head
    pos = (pos + 7) & ~7                 # float64 fields: 8-byte aligned
    if pos + fmt.size > len(body):
        raise ConversionError(f"{field}: message ends inside it "
                              f"({max(len(body) - pos, 0)} of {fmt.size} bytes)")
    _ends_at(body, pos + fmt.size, field)
    return sec, nanosec, frame_id, fmt.unpack_from(body, pos)


def point_stamped_from_cdr(raw: bytes | bytearray | memoryview
                           ) -> tuple[int, int, str, tuple[float, ...]] | None:
    """Decode a serialized ``geometry_msgs/msg/PointStamped`` (with its encapsulation header).

    Returns:
        ``(sec, nanosec, frame_id, (x, y, z))`` as they are in the message (the caller checks
        the values); None when ``raw`` is not little-endian plain CDR.

    Raises:
        ConversionError: a truncated or malformed message (names the field).
    """
    return _stamped_doubles(raw, _POINT, "point")


def pose_cov_stamped_from_cdr(raw: bytes | bytearray | memoryview
                              ) -> tuple[int, int, str, tuple[float, ...], tuple[float, ...]
                                         ] | None:
    """Decode a serialized ``geometry_msgs/msg/PoseWithCovarianceStamped``.

    Returns:
        ``(sec, nanosec, frame_id, (x, y, z, qx, qy, qz, qw), covariance)``, the covariance
        its 36 numbers row by row, as they are in the message; None when ``raw`` is not
        little-endian plain CDR.

    Raises:
        ConversionError: a truncated or malformed message (names the field).
    """
    fields = _stamped_doubles(raw, _POSE_COV, "pose")
    if fields is None:
        return None
    sec, nanosec, frame_id, values = fields
    return sec, nanosec, frame_id, values[:7], values[7:]


def _skip_sequence(body: memoryview, pos: int, item: int, field: str) -> int:
    """The offset after a sequence of ``item``-byte elements. (Its elements need no alignment
    of their own here: a marker's points, the one sequence of float64s, start 8-aligned, 112
    bytes after its 8-aligned pose.)"""
    pos = (pos + 3) & ~3
    if pos + 4 > len(body):
        raise ConversionError(f"{field}: message ends before the sequence length")
    n: int = _U32.unpack_from(body, pos)[0]
    pos += 4
    if pos + n * item > len(body):
        raise ConversionError(f"{field}: {n} elements do not fit the message")
    return pos + n * item


def _marker(body: memoryview, pos: int, where: str) -> tuple[MarkerFields, int]:
    """One ``visualization_msgs/msg/Marker`` at ``pos``: its fields and the offset after it."""
    pos = (pos + 3) & ~3
    if pos + 8 > len(body):
        raise ConversionError(f"{where}.header: message ends inside header.stamp")
    sec, nanosec = _STAMP.unpack_from(body, pos)
    frame_id, pos = _string(body, pos + 8, f"{where}.header.frame_id")
    ns, pos = _string(body, pos, f"{where}.ns")
    pos = (pos + 3) & ~3
    if pos + 12 > len(body):
        raise ConversionError(f"{where}: message ends before id, type and action")
    _id, mtype, action = _I3.unpack_from(body, pos)
    pos = ((pos + 12) + 7) & ~7
    if pos + 80 + 16 + 8 + 1 > len(body):
        raise ConversionError(f"{where}: message ends inside pose, scale, color or lifetime")
    x, y, z, _qx, _qy, _qz, _qw, sx, _sy, _sz = _MARKER_POSE_SCALE.unpack_from(body, pos)
    rgba = _RGBA.unpack_from(body, pos + 80)
    pos += 80 + 16 + 8 + 1                            # lifetime, frame_locked
    pos = _skip_sequence(body, pos, 24, f"{where}.points")
    pos = _skip_sequence(body, pos, 16, f"{where}.colors")
    pos = _string(body, pos, f"{where}.texture_resource")[1]
    pos = (pos + 3) & ~3
    if pos + 8 > len(body):
        raise ConversionError(f"{where}.texture.header: message ends inside its stamp")
    pos = _string(body, pos + 8, f"{where}.texture.header.frame_id")[1]
    pos = _string(body, pos, f"{where}.texture.format")[1]
    pos = _skip_sequence(body, pos, 1, f"{where}.texture.data")
    pos = _skip_sequence(body, pos, 8, f"{where}.uv_coordinates")
    pos = _string(body, pos, f"{where}.text")[1]
    pos = _string(body, pos, f"{where}.mesh_resource")[1]
    pos = _string(body, pos, f"{where}.mesh_file.filename")[1]
    pos = _skip_sequence(body, pos, 1, f"{where}.mesh_file.data")
    if pos + 1 > len(body):
        raise ConversionError(f"{where}.mesh_use_embedded_materials: message ends before it")
    return (sec, nanosec, frame_id, ns, mtype, action, (x, y, z), sx, rgba), pos + 1


def marker_array_from_cdr(raw: bytes | bytearray | memoryview) -> list[MarkerFields] | None:
    """Decode a serialized ``visualization_msgs/msg/MarkerArray``: each marker's header, ``ns``,
    ``type``, ``action``, position, ``scale.x`` and colour (:data:`MarkerFields`), the other
    fields stepped over with their lengths and strings checked (what a generic deserializer
    refuses is refused here), nothing but padding after the last marker.

    Returns:
        The markers' fields in message order, as they are in the message (the caller checks
        them); None when ``raw`` is not little-endian plain CDR.

    Raises:
        ConversionError: a truncated or malformed message (names the marker and field).
    """
    body = _body(raw)
    if body is None:
        return None
    if len(body) < 4:
        raise ConversionError("markers: message ends before the sequence length")
    (n,) = _U32.unpack_from(body, 0)
    if n > len(body) // 100:              # a marker takes more than 100 bytes
        raise ConversionError(f"markers: {n} markers do not fit the message")
    pos, out = 4, []
    for k in range(n):
        fields, pos = _marker(body, pos, f"markers[{k}]")
        out.append(fields)
    _ends_at(body, pos, f"markers[{n - 1}]" if n else "markers")
    return out
