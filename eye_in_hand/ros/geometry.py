"""Geometry messages: ``Pose``/``Transform`` (and their stamped forms) <-> 4x4 ``a_T_b``
matrices, ``Point`` <-> xyz arrays.

Readers are duck-typed (rclpy or rosbags messages) and name the bad field
(``pose.orientation``, ``transform.translation.x`` ...) in their
:class:`eye_in_hand.errors.ConversionError`; builders return rclpy message objects.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from eye_in_hand.core.transforms import (
    as_transform,
    matrix_to_quat_xyzw,
    quat_xyzw_rows,
    quat_xyzw_to_matrix,
)
from eye_in_hand.errors import ConversionError, InputError
from eye_in_hand.ros.fields import field_path, finite, get_field, read_float
from eye_in_hand.ros.stamps import header_or_new

__all__ = [
    "pose_to_matrix",
    "pose_values_to_matrix",
    "pose_stamped_fields",
    "header_fields",
    "point_stamped_fields",
    "pose_cov_stamped_fields",
    "xyz_values",
    "position_covariance",
    "matrix_to_pose",
    "matrix_to_pose_stamped",
    "transform_to_matrix",
    "matrix_to_transform",
    "matrix_to_transform_stamped",
    "point_to_xyz",
    "xyz_to_point",
    "xyz_to_point_stamped",
]


def _xyz(obj: Any, path: str) -> np.ndarray:
    return np.array([read_float(obj, a, path) for a in ("x", "y", "z")])


def _quat_matrix(obj: Any, path: str) -> np.ndarray:
    q = np.array([read_float(obj, a, path) for a in ("x", "y", "z", "w")])
    try:
        return quat_xyzw_to_matrix(q, path)
    except InputError as exc:
        raise ConversionError(str(exc)) from exc


def _checked_transform(T: Any, name: str) -> np.ndarray:
    try:
        return as_transform(T, name)
    except InputError as exc:
        raise ConversionError(str(exc)) from exc


def pose_to_matrix(msg: Any) -> np.ndarray:
    """4x4 transform of a ``Pose``, ``PoseStamped``, ``PoseWithCovariance(Stamped)``.

    For a pose of frame ``b`` given in frame ``a`` (``header.frame_id``) this is ``a_T_b``.

    Raises:
        ConversionError: missing or non-finite fields, zero or far-from-unit quaternion
            (the message names the field, e.g. ``pose.orientation``).
    """
    path = ""
    while hasattr(msg, "pose"):
        msg = msg.pose
        path = field_path(path, "pose")
    o_path = field_path(path, "orientation")
    o = get_field(msg, "orientation", path)
    x, y, z, w = (read_float(o, a, o_path) for a in ("x", "y", "z", "w"))
    rows = _rotation_rows(x, y, z, w, o_path)
    p_path = field_path(path, "position")
    p = get_field(msg, "position", path)
    tx, ty, tz = (read_float(p, a, p_path) for a in ("x", "y", "z"))
    return _pose_array(rows, tx, ty, tz)


def pose_values_to_matrix(values: tuple[float, ...], path: str = "") -> np.ndarray:
    """:func:`pose_to_matrix` of a ``Pose`` given as its seven numbers ``(x, y, z, qx, qy,
    qz, qw)`` (``eye_in_hand.io.cdr.pose_stamped_from_cdr``'s): the same checks in the same
    order, the same errors (fields named under ``path``), the same matrix to the bit."""
    tx, ty, tz, x, y, z, w = values
    o_path = field_path(path, "orientation")
    x, y, z, w = (finite(x, f"{o_path}.x"), finite(y, f"{o_path}.y"), finite(z, f"{o_path}.z"),
                  finite(w, f"{o_path}.w"))
    rows = _rotation_rows(x, y, z, w, o_path)
    p_path = field_path(path, "position")
    return _pose_array(rows, finite(tx, f"{p_path}.x"), finite(ty, f"{p_path}.y"),
                       finite(tz, f"{p_path}.z"))


def header_fields(msg: Any, path: str = "") -> tuple[int, int, str]:
    """``(sec, nanosec, frame_id)`` of a stamped message object's header (a missing field
    named under ``path``), as ``eye_in_hand.io.cdr``'s readers give them."""
    h_path = field_path(path, "header")
    header = get_field(msg, "header", path)
    stamp = get_field(header, "stamp", h_path)
    return (get_field(stamp, "sec", f"{h_path}.stamp"),
            get_field(stamp, "nanosec", f"{h_path}.stamp"), get_field(header, "frame_id", h_path))


def _pose_fields(pose: Any, path: str) -> tuple[float, ...]:
    """``(x, y, z, qx, qy, qz, qw)`` of a ``Pose`` object found at ``path``."""
    p = get_field(pose, "position", path)
    o = get_field(pose, "orientation", path)
    return (tuple(get_field(p, a, f"{path}.position") for a in ("x", "y", "z"))
            + tuple(get_field(o, a, f"{path}.orientation") for a in ("x", "y", "z", "w")))


def pose_stamped_fields(msg: Any) -> tuple[int, int, str, tuple[float, ...]]:
    """``(sec, nanosec, frame_id, (x, y, z, qx, qy, qz, qw))`` of a ``PoseStamped`` message
    object (rclpy or rosbags), as ``eye_in_hand.io.cdr.pose_stamped_from_cdr`` reads them
    from its bytes; nothing checked beyond the fields being there.

    Raises:
        ConversionError: a missing field (named).
    """
    return (*header_fields(msg), _pose_fields(get_field(msg, "pose", ""), "pose"))


def point_stamped_fields(msg: Any) -> tuple[int, int, str, tuple[float, ...]]:
    """``(sec, nanosec, frame_id, (x, y, z))`` of a ``PointStamped`` message object (rclpy or
    rosbags), as ``eye_in_hand.io.cdr.point_stamped_from_cdr`` reads them from its bytes;
    nothing checked beyond the fields being there.

    Raises:
        ConversionError: a missing field (named).
    """
    p = get_field(msg, "point", "")
    return (*header_fields(msg), tuple(get_field(p, a, "point") for a in ("x", "y", "z")))


def pose_cov_stamped_fields(msg: Any
                            ) -> tuple[int, int, str, tuple[float, ...], tuple[float, ...]]:
    """``(sec, nanosec, frame_id, (x, y, z, qx, qy, qz, qw), covariance (36))`` of a
    ``PoseWithCovarianceStamped`` message object, as ``eye_in_hand.io.cdr.
    pose_cov_stamped_from_cdr`` reads them from its bytes; nothing checked beyond the fields
    being there.

    Raises:
        ConversionError: a missing field (named).
    """
    with_cov = get_field(msg, "pose", "")
    return (*header_fields(msg), _pose_fields(get_field(with_cov, "pose", "pose"), "pose.pose"),
            tuple(get_field(with_cov, "covariance", "pose")))


def xyz_values(values: tuple[float, ...], path: str) -> np.ndarray:
    """(3,) float64 of three numbers read from a message (``point_stamped_fields``'s), which
    must be finite: the array and the errors of :func:`point_to_xyz` (``<path>.x`` named)."""
    if len(values) != 3:
        raise ConversionError(f"{path}: expected x, y, z, got {len(values)} numbers")
    out = []
    for v, a in zip(values, "xyz", strict=True):
        try:
            f = float(v)
        except (TypeError, ValueError) as exc:
            raise ConversionError(f"{path}.{a}: expected a number, got {v!r}") from exc
        out.append(finite(f, f"{path}.{a}"))
    return np.array(out)


def position_covariance(values: Any, path: str) -> np.ndarray:
    """The 3x3 position block (float64, C-ordered) of a ``PoseWithCovariance``'s 6x6
    row-major covariance given as its 36 numbers (``pose_cov_stamped_fields``'s): the values
    of ``reshape(6, 6)[:3, :3]``, not checked for finiteness (the caller's rule).

    Raises:
        ConversionError: not 36 numbers (``path`` named).
    """
    if len(values) != 36:
        raise ConversionError(f"{path}: expected 36 numbers, got {len(values)}")
    try:
        return np.array((values[0:3], values[6:9], values[12:15]), dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ConversionError(f"{path}: expected numbers ({exc})") from exc


def _rotation_rows(x: float, y: float, z: float, w: float, o_path: str) -> list[list[float]]:
    try:
        return quat_xyzw_rows(x, y, z, w, o_path)
    except InputError as exc:
        raise ConversionError(str(exc)) from exc


def _pose_array(rows: list[list[float]], tx: float, ty: float, tz: float) -> np.ndarray:
    # one array of Python floats (on every robot pose: no 4x4 identity filled slice by slice)
    r0, r1, r2 = rows
    return np.array([[r0[0], r0[1], r0[2], tx], [r1[0], r1[1], r1[2], ty],
                     [r2[0], r2[1], r2[2], tz], [0.0, 0.0, 0.0, 1.0]])


def transform_to_matrix(msg: Any) -> np.ndarray:
    """4x4 transform of a ``Transform`` or ``TransformStamped``.

    A ``TransformStamped`` with ``header.frame_id = a`` and ``child_frame_id = b`` gives ``a_T_b``.

    Raises:
        ConversionError: missing or non-finite fields, bad quaternion (naming the field).
    """
    path = ""
    if hasattr(msg, "transform"):
        msg = msg.transform
        path = "transform"
    T = np.eye(4)
    T[:3, :3] = _quat_matrix(get_field(msg, "rotation", path), field_path(path, "rotation"))
    T[:3, 3] = _xyz(get_field(msg, "translation", path), field_path(path, "translation"))
    return T


def point_to_xyz(msg: Any) -> np.ndarray:
    """(3,) float64 of a ``Point``, ``PointStamped``, ``Point32`` or ``Vector3``.

    Raises:
        ConversionError: missing or non-finite coordinates (naming the field).
    """
    path = ""
    if hasattr(msg, "point"):
        msg = msg.point
        path = "point"
    return _xyz(msg, path)


def matrix_to_pose(T: Any) -> Any:
    """A ``geometry_msgs.msg.Pose`` from a 4x4 transform (quaternion with w >= 0).

    Raises:
        ConversionError: not a finite rigid transform.
    """
    # local: message packages are the optional [ros] extra; decoding and offline code import
    # this module without them
    from geometry_msgs.msg import Point, Pose, Quaternion

    arr = _checked_transform(T, "T")
    q = matrix_to_quat_xyzw(arr[:3, :3])
    t = arr[:3, 3]
    return Pose(position=Point(x=float(t[0]), y=float(t[1]), z=float(t[2])),
                orientation=Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]),
                                       w=float(q[3])))


def matrix_to_pose_stamped(T: Any, *, stamp_ns: int = 0, frame_id: str = "",
                           header: Any = None) -> Any:
    """A ``geometry_msgs.msg.PoseStamped`` from ``frame_id_T_pose`` (4x4)."""
    # local: message packages are the optional [ros] extra; decoding and offline code import
    # this module without them
    from geometry_msgs.msg import PoseStamped

    pose = matrix_to_pose(T)
    return PoseStamped(header=header_or_new(header, stamp_ns, frame_id), pose=pose)


def matrix_to_transform(T: Any) -> Any:
    """A ``geometry_msgs.msg.Transform`` from a 4x4 transform."""
    # local: message packages are the optional [ros] extra; decoding and offline code import
    # this module without them
    from geometry_msgs.msg import Quaternion, Transform, Vector3

    pose = matrix_to_pose(T)
    p, q = pose.position, pose.orientation
    return Transform(translation=Vector3(x=p.x, y=p.y, z=p.z),
                     rotation=Quaternion(x=q.x, y=q.y, z=q.z, w=q.w))


def matrix_to_transform_stamped(T: Any, *, stamp_ns: int = 0, frame_id: str = "",
                                child_frame_id: str = "", header: Any = None) -> Any:
    """A ``geometry_msgs.msg.TransformStamped`` from ``frame_id_T_child_frame_id`` (4x4)."""
    # local: message packages are the optional [ros] extra; decoding and offline code import
    # this module without them
    from geometry_msgs.msg import TransformStamped

    if not isinstance(child_frame_id, str):
        raise ConversionError(f"child_frame_id: expected a string, got {child_frame_id!r}")
    return TransformStamped(header=header_or_new(header, stamp_ns, frame_id),
                            child_frame_id=child_frame_id, transform=matrix_to_transform(T))


def _checked_xyz(xyz: Any) -> np.ndarray:
    try:
        arr = np.asarray(xyz, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise ConversionError(f"xyz: expected 3 numbers, got {xyz!r}") from exc
    if arr.shape != (3,):
        raise ConversionError(f"xyz: expected 3 values, got shape {np.shape(xyz)}")
    if not np.all(np.isfinite(arr)):
        raise ConversionError(f"xyz: contains NaN or infinite values: {arr.tolist()}")
    return arr


def xyz_to_point(xyz: Any) -> Any:
    """A ``geometry_msgs.msg.Point`` from array-like shape (3,)."""
    # local: message packages are the optional [ros] extra; decoding and offline code import
    # this module without them
    from geometry_msgs.msg import Point

    v = _checked_xyz(xyz)
    return Point(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def xyz_to_point_stamped(xyz: Any, *, stamp_ns: int = 0, frame_id: str = "",
                         header: Any = None) -> Any:
    """A ``geometry_msgs.msg.PointStamped`` from array-like shape (3,)."""
    # local: message packages are the optional [ros] extra; decoding and offline code import
    # this module without them
    from geometry_msgs.msg import PointStamped

    return PointStamped(header=header_or_new(header, stamp_ns, frame_id), point=xyz_to_point(xyz))
