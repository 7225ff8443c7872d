"""The localization's output messages, built once for the live nodes and for ``process``.

``detect_triangulate`` and ``hand_eye`` publish these messages with rclpy; ``eye-in-hand
process`` writes the same messages into its output bag with rosbags, without rclpy. Both build
them here, from the same numbers, so that an offline output bag replays into RViz (or any
subscriber) exactly as the live run would have published it (docs/localization.md "Offline =
live").

Every builder takes ``T``, a lookup ``msgtype -> message class``:

* :func:`rclpy_types` (the installed ROS interface packages), for the nodes;
* :class:`RosbagsTypes` (a rosbags type store), for bags: rosbags classes have no field
  defaults, so it fills every field a builder leaves out with its zero value, as rclpy does.

Nothing here imports rclpy or a message package at import time.
"""
from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from eye_in_hand.core.transforms import matrix_to_quat_xyzw
from eye_in_hand.errors import ConfigError, ConversionError

__all__ = ["Sphere", "LocatedFrame", "OutputSettings", "DEFAULT_RGBA", "TARGET_FRAME_PREFIX",
           "MARKER_LIFETIME_S",
           "MARKER_DIAMETER_M", "RIGHT_CAMERA_FRAME", "UNKNOWN_ROTATION_VARIANCE",
           "MARKER_SPHERE", "MARKER_ADD", "MARKER_DELETEALL",
           "RosbagsTypes", "rclpy_types", "checked_xyz", "checked_frame", "stamp_parts",
           "point_pose_covariance",
           "marker_lifetime_ns", "checked_spheres",
           "time_msg", "header", "point_stamped", "pose_with_covariance", "pose_stamped",
           "point_pose_messages",
           "pose_array", "sphere_markers", "transform_stamped", "tf_message",
           "translation_tf_message"]

#: Colour of a sphere whose target has no usable hue (r, g, b, a in 0..1).
DEFAULT_RGBA = (1.0, 1.0, 1.0, 0.8)
#: Every target's /tf child frame is this prefix + its id (hand_eye ``target_frame_prefix``).
TARGET_FRAME_PREFIX = "target_"
#: Lifetime of the spheres on targets/markers and target/markers (s; the nodes' default).
MARKER_LIFETIME_S = 1.0
#: Sphere diameter on the markers of a target of unknown radius (m; the nodes' default).
MARKER_DIAMETER_M = 0.04
#: The right optical frame id (hand_eye ``right_camera_frame``).
RIGHT_CAMERA_FRAME = "camera_right_optical_frame"
#: Orientation variance (rad^2) of a point published as a pose: unknown.
UNKNOWN_ROTATION_VARIANCE = 1e6

_NS_PER_S = 1_000_000_000
_INT32 = (-(2 ** 31), 2 ** 31 - 1)
_FLOAT32_MAX = float(np.finfo(np.float32).max)
#: visualization_msgs/Marker type and actions of the sphere markers
MARKER_SPHERE, MARKER_ADD, MARKER_DELETEALL = 2, 0, 3

#: Field defaults of ROS message definitions that are not zero (rosbags does not keep them).
_NONZERO_DEFAULTS: dict[str, dict[str, Any]] = {"geometry_msgs/msg/Quaternion": {"w": 1.0}}


@dataclass(frozen=True)
class Sphere:
    """One target as a sphere.

    Attributes:
        id: the target id (the marker's ``ns``).
        xyz: centre, shape (3,), metres, in the message's frame.
        diameter_m: the sphere's diameter (metres, > 0).
        rgba: colour, four floats in 0..1.
    """

    id: str
    xyz: np.ndarray
    diameter_m: float
    rgba: tuple[float, float, float, float] = DEFAULT_RGBA


@dataclass(frozen=True)
class LocatedFrame:
    """One located stereo pair, handed from a detector to ``hand_eye`` in the same process
    (:meth:`eye_in_hand.nodes.hand_eye.HandEyeNode.deliver`): what ``target/point(_cov)``,
    ``targets/<id>/point_cov`` and ``targets/markers`` carry over DDS.

    Attributes:
        stamp_ns: the left image's stamp.
        frame_id: the camera frame of the points.
        first: the first configured target's point (3,) and covariance (3, 3), or None.
        targets: every published target: its sphere (id, centre = camera point, diameter,
            colour) and covariance (3, 3), in the order of ``targets/markers``.
    """

    stamp_ns: int
    frame_id: str
    first: tuple[np.ndarray, np.ndarray] | None
    targets: tuple[tuple[Sphere, np.ndarray], ...]


@dataclass(frozen=True)
class OutputSettings:
    """What the live nodes' parameters decide about their outputs, for ``process`` to write
    the same messages (the defaults are the nodes' defaults).

    Attributes:
        target_frame_prefix, target_frame, publish_tf, right_camera_frame: hand_eye's
            parameters of those names.
        camera_markers_lifetime_s: detect_triangulate ``markers.lifetime_s``.
        target_markers_lifetime_s: hand_eye ``marker_lifetime_s``.
        styles: target name -> (sphere diameter (m), rgba) on the markers
            (:func:`eye_in_hand.ros.markers.sphere_style` of the target's configuration).
        default_style: the style of a target of no configured name.
        camera_parent: the parent frame of the camera on /tf_static (ee_frame; base_frame for
            a fixed camera).
        hand_eye_T: ``camera_parent_T_camera`` (4x4) for /tf_static and hand_eye/transform.
        stereo_T: ``camera_T_right_camera`` (4x4) from hand_eye's ``stereo_calibration_dir``,
            or None (no stereo extrinsic on /tf_static).
    """

    target_frame_prefix: str = TARGET_FRAME_PREFIX
    target_frame: str = ""
    publish_tf: bool = True
    right_camera_frame: str = RIGHT_CAMERA_FRAME
    camera_markers_lifetime_s: float = MARKER_LIFETIME_S
    target_markers_lifetime_s: float = MARKER_LIFETIME_S
    styles: Mapping[str, tuple[float, tuple[float, float, float, float]]] = \
        dataclasses.field(default_factory=dict)
    default_style: tuple[float, tuple[float, float, float, float]] = (MARKER_DIAMETER_M,
                                                                      DEFAULT_RGBA)
    camera_parent: str = "tool0"
    hand_eye_T: np.ndarray | None = None
    stereo_T: np.ndarray | None = None

    def style(self, name: str) -> tuple[float, tuple[float, float, float, float]]:
        return self.styles.get(name, self.default_style)


# -- message classes --------------------------------------------------------------------------
class _RclpyTypes:
    """``T[msgtype]``: the installed rclpy message class."""

    def __init__(self) -> None:
        self._classes: dict[str, Any] = {}

    def __getitem__(self, msgtype: str) -> Any:
        cls = self._classes.get(msgtype)
        if cls is None:
            cls = self._classes[msgtype] = _rclpy_class(msgtype)
        return cls


@functools.cache
def _rclpy_class(msgtype: str) -> Any:
    from eye_in_hand.ros.msgtypes import import_message_type  # local: rclpy, live path only

    cls = import_message_type(msgtype)
    if cls is None:
        package = msgtype.split("/", 1)[0]
        raise ConfigError(f"{package} is not installed: no {msgtype} can be published (it "
                          "comes with ros-jazzy-common-interfaces; tf2_msgs with 'make venv')")
    return cls


def rclpy_types() -> Any:
    """The message classes of the installed ROS interface packages (``T[msgtype]``)."""
    return _RCLPY


_RCLPY = _RclpyTypes()

_NUMPY_DTYPES = {"float64": np.float64, "float32": np.float32, "int8": np.int8,
                 "uint8": np.uint8, "byte": np.uint8, "char": np.uint8, "int16": np.int16,
                 "uint16": np.uint16, "int32": np.int32, "uint32": np.uint32,
                 "int64": np.int64, "uint64": np.uint64, "bool": np.bool_}


class RosbagsTypes:
    """``T[msgtype]`` over a rosbags type store: a constructor that fills every field not given
    with its zero value (rclpy's defaults), so builders name only the fields they set."""

    def __init__(self, typestore: Any) -> None:
        self.typestore = typestore
        self._factories: dict[str, Callable[..., Any]] = {}

    def __getitem__(self, msgtype: str) -> Callable[..., Any]:
        factory = self._factories.get(msgtype)
        if factory is None:
            factory = self._factories[msgtype] = self._factory(msgtype)
        return factory

    def _factory(self, msgtype: str) -> Callable[..., Any]:
        cls = self.typestore.types[msgtype]
        _, fields = self.typestore.fielddefs[msgtype]
        defaults: dict[str, Callable[[], Any]] = {name: self._default_of(desc)
                                                  for name, desc in fields}
        for name, value in _NONZERO_DEFAULTS.get(msgtype, {}).items():
            def constant(v: Any = value) -> Any:
                return v

            defaults[name] = constant

        makers = tuple(defaults.values())
        # the builders call it without arguments for every message and sub-message of
        # `process`'s output bag: then the fields go in positionally, in the class's order
        # (rosbags' classes end with a defaulted ``__msgtype__`` field)
        fields_ = dataclasses.fields(cls)
        positional = [f.name for f in fields_[:len(defaults)]] == list(defaults) and all(
            f.default is not dataclasses.MISSING for f in fields_[len(defaults):])

        def make(**kwargs: Any) -> Any:
            if not kwargs and positional:
                return cls(*[make_default() for make_default in makers])
            values = {name: (kwargs.pop(name) if name in kwargs else make_default())
                      for name, make_default in defaults.items()}
            if kwargs:
                raise TypeError(f"{msgtype} has no field(s) {sorted(kwargs)}")
            return cls(**values)

        return make

    def _default_of(self, desc: Any) -> Callable[[], Any]:
        kind, detail = desc
        kind = int(kind)
        if kind == 1:                                   # a base type
            name = detail[0]
            if name == "string":
                return str
            if name == "bool":
                return bool
            return (lambda: 0.0) if name.startswith("float") else int
        if kind == 2:                                   # a message
            return lambda: self[detail]()
        sub, length = detail
        sub_kind, sub_detail = int(sub[0]), sub[1]
        if sub_kind == 1 and sub_detail[0] != "string":
            dtype = _NUMPY_DTYPES[sub_detail[0]]
            n = length if kind == 3 else 0
            return lambda: np.zeros(n, dtype=dtype)
        item = self._default_of(sub)
        n = length if kind == 3 else 0
        return lambda: [item() for _ in range(n)]


# -- checks -----------------------------------------------------------------------------------
def checked_xyz(xyz: Any, what: str) -> tuple[float, float, float]:
    """Three finite floats of an array-like of 3 numbers (any shape holding 3 values)."""
    try:
        if isinstance(xyz, np.ndarray) and xyz.shape != (3,):
            xyz = xyz.reshape(-1)
        x, y, z = xyz
        out = (float(x), float(y), float(z))
    except (TypeError, ValueError) as exc:
        raise ConversionError(f"{what}: expected 3 finite numbers, got {xyz!r}") from exc
    if not (math.isfinite(out[0]) and math.isfinite(out[1]) and math.isfinite(out[2])):
        raise ConversionError(f"{what}: expected 3 finite numbers, got {list(out)}")
    return out


# -- builders ---------------------------------------------------------------------------------
def time_msg(T: Any, stamp_ns: int) -> Any:
    """``builtin_interfaces/Time`` of int nanoseconds.

    Raises:
        ConversionError: not an integer, or seconds outside int32.
    """
    t = T["builtin_interfaces/msg/Time"]()
    t.sec, t.nanosec = stamp_parts(stamp_ns)
    return t


def stamp_parts(stamp_ns: int) -> tuple[int, int]:
    """``(sec, nanosec)`` of a ``builtin_interfaces/Time`` of int nanoseconds.

    Raises:
        ConversionError: not an integer, or seconds outside int32.
    """
    if isinstance(stamp_ns, (bool, np.bool_)) or not isinstance(stamp_ns, (int, np.integer)):
        raise ConversionError(
            f"stamp_ns: expected int nanoseconds, got {type(stamp_ns).__name__} {stamp_ns!r}")
    sec, nanosec = divmod(int(stamp_ns), _NS_PER_S)
    if not _INT32[0] <= sec <= _INT32[1]:
        raise ConversionError(f"stamp_ns: {stamp_ns} does not fit builtin_interfaces/Time")
    return sec, nanosec


def header(T: Any, stamp_ns: int, frame_id: str) -> Any:
    """``std_msgs/Header``."""
    frame_id = checked_frame(frame_id)
    h = T["std_msgs/msg/Header"]()
    h.stamp = time_msg(T, stamp_ns)
    h.frame_id = frame_id
    return h


def checked_frame(frame_id: Any) -> str:
    """A frame id, which must be a str.

    Raises:
        ConversionError: not a str.
    """
    if not isinstance(frame_id, str):
        raise ConversionError(f"frame_id: expected a string, got {frame_id!r}")
    return frame_id


# Builders fill default-constructed messages field by field (rclpy's keyword constructors build
# every default sub-message first and then replace it: about 2-3x the time per message).
def _set_xyz(obj: Any, p: Any) -> None:
    obj.x, obj.y, obj.z = float(p[0]), float(p[1]), float(p[2])


def _set_position_pose(pose: Any, p: Any) -> None:
    """A pose at ``p`` with the identity orientation."""
    _set_xyz(pose.position, p)
    pose.orientation.w = 1.0


def point_stamped(T: Any, xyz: Any, stamp_ns: int, frame_id: str) -> Any:
    """``geometry_msgs/PointStamped`` (``target/point``).

    Raises:
        ConversionError: not 3 finite numbers, or a bad stamp or frame.
    """
    p = checked_xyz(xyz, "point")
    msg = T["geometry_msgs/msg/PointStamped"]()
    msg.header = header(T, stamp_ns, frame_id)
    _set_xyz(msg.point, p)
    return msg


def pose_with_covariance(T: Any, xyz: Any, cov: Any, stamp_ns: int, frame_id: str,
                         hdr: Any = None) -> Any:
    """``geometry_msgs/PoseWithCovarianceStamped`` of a point: position = the point,
    orientation identity, covariance position block ``cov`` (3x3, m^2), orientation variances
    :data:`UNKNOWN_ROTATION_VARIANCE` (``target/point_cov``, ``target/pose_cov``)."""
    p = checked_xyz(xyz, "point")
    msg = T["geometry_msgs/msg/PoseWithCovarianceStamped"]()
    msg.header = hdr if hdr is not None else header(T, stamp_ns, frame_id)
    _set_position_pose(msg.pose.pose, p)
    msg.pose.covariance = point_pose_covariance(cov)       # float64 (36,): taken as it is
    return msg


def point_pose_covariance(cov: Any) -> np.ndarray:
    """The 36 covariance values (row-major 6x6, float64) of a point published as a pose: the
    position block ``cov`` (3x3, m^2), orientation variances :data:`UNKNOWN_ROTATION_VARIANCE`."""
    full = np.zeros((6, 6))
    full[:3, :3] = np.asarray(cov, dtype=np.float64).reshape(3, 3)
    full[3:, 3:] = np.eye(3) * UNKNOWN_ROTATION_VARIANCE
    return full.ravel()


def pose_stamped(T: Any, xyz: Any, stamp_ns: int, frame_id: str, hdr: Any = None) -> Any:
    """``geometry_msgs/PoseStamped`` of a point: orientation identity (``target/pose``)."""
    p = checked_xyz(xyz, "point")
    msg = T["geometry_msgs/msg/PoseStamped"]()
    msg.header = hdr if hdr is not None else header(T, stamp_ns, frame_id)
    _set_position_pose(msg.pose, p)
    return msg


def point_pose_messages(T: Any, xyz: Any, cov: Any, stamp_ns: int, frame_id: str
                        ) -> tuple[Any, Any]:
    """``geometry_msgs/PoseStamped`` and ``PoseWithCovarianceStamped`` of a located point
    (3,) and its covariance (3, 3), sharing one header: :func:`pose_stamped` and
    :func:`pose_with_covariance` (``target/pose(_cov)``, ``target/<id>/pose(_cov)``).

    Raises:
        ConversionError: the point is not finite, or a bad stamp or frame.
    """
    if not np.all(np.isfinite(xyz)):
        raise ConversionError(f"base-frame point is not finite: {xyz}")
    hdr = header(T, stamp_ns, frame_id)
    return (pose_stamped(T, xyz, stamp_ns, "", hdr),
            pose_with_covariance(T, xyz, cov, stamp_ns, "", hdr))


def pose_array(T: Any, points: Iterable[Any], stamp_ns: int, frame_id: str) -> Any:
    """``geometry_msgs/PoseArray``: one pose per point, orientation identity
    (``target/poses``).

    Raises:
        ConversionError: a point is not 3 finite numbers.
    """
    Pose = T["geometry_msgs/msg/Pose"]
    poses = []
    for k, p in enumerate(points):
        pose = Pose()
        _set_position_pose(pose, checked_xyz(p, f"points[{k}]"))
        poses.append(pose)
    msg = T["geometry_msgs/msg/PoseArray"]()
    msg.header = header(T, stamp_ns, frame_id)
    msg.poses = poses
    return msg


def sphere_markers(T: Any, spheres: Iterable[Sphere], stamp_ns: int, frame_id: str,
                   lifetime_s: float = 0.0) -> Any:
    """``visualization_msgs/MarkerArray``: ``DELETEALL``, then one ``SPHERE`` (``ns`` = id,
    ``id`` 0) per sphere (``targets/markers``, ``target/markers``).

    Raises:
        ConversionError: a non-finite centre, a diameter that is not positive, two spheres
            with one id, a colour that is not 4 finite float32 values, or a lifetime that
            does not fit a Duration.
    """
    Marker = T["visualization_msgs/msg/Marker"]
    hdr = header(T, stamp_ns, frame_id)
    clear = Marker()
    clear.header, clear.action = hdr, MARKER_DELETEALL
    out = [clear]
    life = marker_lifetime_ns(lifetime_s)
    for s, xyz in checked_spheres(spheres):
        m = Marker()
        m.header, m.ns, m.id, m.type, m.action = hdr, s.id, 0, MARKER_SPHERE, MARKER_ADD
        _set_position_pose(m.pose, xyz)
        m.scale.x = m.scale.y = m.scale.z = float(s.diameter_m)
        m.color.r, m.color.g, m.color.b, m.color.a = (float(c) for c in s.rgba)
        m.lifetime.sec, m.lifetime.nanosec = divmod(life, _NS_PER_S)
        out.append(m)
    msg = T["visualization_msgs/msg/MarkerArray"]()
    msg.markers = out
    return msg


def marker_lifetime_ns(lifetime_s: float) -> int:
    """A sphere's lifetime on the markers, int ns (0: until replaced or deleted).

    Raises:
        ConversionError: not a finite number, or longer than ``builtin_interfaces/Duration``
            holds (2^31 - 1 s).
    """
    if not math.isfinite(lifetime_s):
        raise ConversionError(f"marker lifetime: expected a finite number of seconds, got "
                              f"{lifetime_s!r}")
    life = max(0, int(round(lifetime_s * 1e9)))
    if life // _NS_PER_S > _INT32[1]:
        raise ConversionError(f"marker lifetime: {lifetime_s} s does not fit "
                              "builtin_interfaces/Duration (at most 2147483647 s)")
    return life


def checked_spheres(spheres: Iterable[Sphere]) -> Iterable[tuple[Sphere, tuple[float, float,
                                                                                 float]]]:
    """``(sphere, centre)`` of each sphere of a frame's markers, checked.

    Raises:
        ConversionError: a non-finite centre, a diameter that is not positive, two spheres
            with one id, or a colour that is not 4 finite float32 values.
    """
    seen: set[str] = set()
    for s in spheres:
        xyz = checked_xyz(s.xyz, f"sphere '{s.id}': centre")
        if not (math.isfinite(s.diameter_m) and s.diameter_m > 0):
            raise ConversionError(f"sphere '{s.id}': diameter must be > 0, got {s.diameter_m}")
        if s.id in seen:
            raise ConversionError(f"sphere '{s.id}': two spheres with one id in a frame")
        if len(s.rgba) != 4 or not all(math.isfinite(c) and abs(c) <= _FLOAT32_MAX
                                       for c in s.rgba):
            raise ConversionError(f"sphere '{s.id}': colour must be 4 finite float32 values "
                                  f"(r, g, b, a), got {tuple(s.rgba)!r}")
        seen.add(s.id)
        yield s, xyz


def transform_stamped(T: Any, parent_T_child: Any, stamp_ns: int, parent: str,
                      child: str) -> Any:
    """``geometry_msgs/TransformStamped`` of a 4x4 rigid transform (quaternion w >= 0).

    Raises:
        ConversionError: not a finite 4x4 transform, or a bad stamp or frame.
    """
    M = np.asarray(parent_T_child, dtype=np.float64)
    if M.shape != (4, 4) or not np.all(np.isfinite(M)):
        raise ConversionError(f"transform {parent} -> {child}: expected a finite 4x4 matrix")
    if not isinstance(child, str):
        raise ConversionError(f"child_frame_id: expected a string, got {child!r}")
    q = matrix_to_quat_xyzw(M[:3, :3])
    msg = T["geometry_msgs/msg/TransformStamped"]()
    msg.header = header(T, stamp_ns, parent)
    msg.child_frame_id = child
    _set_xyz(msg.transform.translation, M[:3, 3])
    r = msg.transform.rotation
    r.x, r.y, r.z, r.w = float(q[0]), float(q[1]), float(q[2]), float(q[3])
    return msg


def tf_message(T: Any, edges: Iterable[tuple[str, str, int, Any]]) -> Any:
    """``tf2_msgs/TFMessage`` of ``(parent, child, stamp_ns, parent_T_child 4x4)``."""
    msg = T["tf2_msgs/msg/TFMessage"]()
    msg.transforms = [transform_stamped(T, M, int(stamp), parent, child)
                      for parent, child, stamp, M in edges]
    return msg


def translation_tf_message(T: Any, edges: Iterable[tuple[str, str, int, Any]]) -> Any:
    """``tf2_msgs/TFMessage`` of translation-only transforms ``(parent, child, stamp_ns,
    translation (3,))``, rotation identity: the message :func:`tf_message` builds of the 4x4
    transforms, without a rotation conversion (per target and frame on the live path).

    Raises:
        ConversionError: a translation is not 3 finite numbers.
    """
    Transform = T["geometry_msgs/msg/TransformStamped"]
    out = []
    for parent, child, stamp, t in edges:
        p = checked_xyz(t, f"translation of {parent} -> {child}")
        tr = Transform()
        tr.header = header(T, int(stamp), parent)
        tr.child_frame_id = child
        _set_xyz(tr.transform.translation, p)
        tr.transform.rotation.w = 1.0
        out.append(tr)
    msg = T["tf2_msgs/msg/TFMessage"]()
    msg.transforms = out
    return msg
