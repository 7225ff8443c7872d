"""Calibration samples from a bag: the still robot stops of a recording, their images and the
robot pose at each image stamp (from a pose topic, joint states + kinematics, or ``/tf``).
"""
from __future__ import annotations

import os
import struct
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.core.sync import PoseBuffer
from eye_in_hand.core.tf import TfBuffer
from eye_in_hand.errors import (
    BagError,
    ConfigError,
    ConversionError,
    InputError,
    LocalizationError,
)
from eye_in_hand.io.bags import DamageLog, bag_info, deserialize, typestore_for
from eye_in_hand.io.bags import iter_messages as _iter_messages
from eye_in_hand.ros.camera_info import camera_info_to_model
from eye_in_hand.ros.geometry import pose_to_matrix, transform_to_matrix
from eye_in_hand.ros.images import calibration_image
from eye_in_hand.ros.stamps import header_stamp_ns

__all__ = ["BagSample", "BagSamples", "read_bag_samples"]


@dataclass(frozen=True)
class BagSample:
    """One still robot stop found in a bag.

    Attributes:
        name: ``stopNNN``.
        stamp_ns: the image stamp (header) used.
        images: decoded images by view name (``image`` mono, ``left``/``right`` stereo).
        base_T_ee: robot pose interpolated at ``stamp_ns``, shape (4, 4).
    """

    name: str
    stamp_ns: int
    images: Mapping[str, np.ndarray]
    base_T_ee: np.ndarray


@dataclass(frozen=True)
class BagSamples:
    """What :func:`read_bag_samples` found.

    Attributes:
        samples: one per still robot stop.
        camera: mono camera from the bag's camera_info (None when stereo or absent).
        rig: stereo rig from the bag's two camera_info topics (None when mono or absent).
        image_topics: the image topics used, by view name.
        pose_source: description of the robot pose source.
        skipped: images not used and why (``{"stamp_ns", "reason"}``), e.g. robot moving.
        n_images: number of (reference) images in the bag.
        ground_truth: ``ee_T_cam`` when the bag has ``/ground_truth/hand_eye`` (simulator).
        damage: the parts of the bag skipped as damaged (an
            :class:`eye_in_hand.io.bags.DamageLog`): unreadable chunks, truncated tails, and
            messages that do not decode, truncated images, non-finite poses (each naming
            topic and stamp).
    """

    samples: tuple[BagSample, ...]
    camera: CameraModel | None
    rig: StereoRig | None
    image_topics: Mapping[str, str]
    pose_source: str
    skipped: tuple[dict[str, Any], ...]
    n_images: int
    ground_truth: Mapping[str, np.ndarray] = field(default_factory=dict)
    damage: Any = None


def _robot_series(topics: Mapping[str, Any], topic: str) -> PoseBuffer:
    """A buffer for every robot pose of ``topic`` (its message count)."""
    return PoseBuffer(max(2, topics[topic].count), name="robot pose")


def _pose_at(series: PoseBuffer, stamp_ns: int) -> np.ndarray | None:
    """The robot pose interpolated at ``stamp_ns``, None outside the poses' time range."""
    try:
        return series.lookup(stamp_ns, _ANY_GAP_NS)
    except LocalizationError:
        return None


def _cdr_header_stamp_ns(raw: bytes) -> int:
    """The ``header.stamp`` of a CDR message whose first field is a ``std_msgs/Header``, read
    without decoding the rest (an image's pixels are not copied)."""
    if len(raw) < 12 or raw[1] not in (0, 1):
        raise ConfigError("message is not plain CDR: cannot read its header stamp")
    sec, nsec = struct.unpack("<iI" if raw[1] == 1 else ">iI", bytes(raw[4:12]))
    return int(sec) * 1_000_000_000 + int(nsec)


def _resolve_topic(topics: Mapping[str, Any], name: str, what: str, source: str) -> str:
    if name in topics:
        return name
    suffix = "/" + name.lstrip("/")
    matches = [t for t in topics if t.endswith(suffix)]
    if len(matches) == 1:
        return matches[0]
    if not matches:
        raise ConfigError(f"{source}: no {what} topic {name!r} (topics: {', '.join(topics)})")
    raise ConfigError(f"{source}: {what} topic {name!r} is ambiguous: {', '.join(matches)}")


def _info_topic(image_topic: str) -> str:
    return image_topic.rsplit("/", 1)[0] + "/camera_info"


#: calibration stops take the robot pose interpolated between any two poses: the stillness test
#: checks the poses around each image
_ANY_GAP_NS = 2 ** 62


def _tf_series(tf: TfBuffer, stamps_by_child: Mapping[str, list[int]], base: str, tip: str,
               source: str) -> PoseBuffer:
    """``base_T_tip`` at every stamp of the dynamic /tf edge nearest the tip (the chain's
    clock), looked up in ``tf``; a stamp where an edge of the chain has no bracket is left
    out."""
    chain: list[str] = []                   # frames from the tip up to the base
    frame = tip
    while frame != base:
        parent = tf.parent(frame)
        if parent is None:
            raise ConfigError(f"{source}: /tf has no chain from {base!r} to {tip!r} (stuck at "
                              f"{frame!r})")
        chain.append(frame)
        frame = parent
    dynamic = [f for f in chain if not tf.is_static(f)]
    if not dynamic:
        raise ConfigError(f"{source}: the /tf chain {base!r} -> {tip!r} is static")
    stamps = sorted(set(stamps_by_child.get(dynamic[0], ())))
    series = PoseBuffer(max(2, len(stamps)), name=f"{base} -> {tip}")
    for stamp in stamps:
        try:
            series.add(stamp, tf.lookup(base, tip, stamp, _ANY_GAP_NS))
        except LocalizationError:
            continue
    return series



#: what makes a message of the bag unusable: recorded in the damage log, the rest is read
_UNUSABLE = (BagError, ConversionError, InputError, ConfigError, ValueError)


@dataclass
class _Bag:
    """The bag being read, as its passes share it: topics, type store, damage log."""

    path: str | os.PathLike[str]
    topics: Mapping[str, Any]
    store: Any
    log: Any

    @property
    def source(self) -> str:
        return str(self.path)

    def messages(self, wanted: list[str]) -> Iterator[tuple[str, str, int, Any]]:
        """The bag's messages, damaged parts skipped and recorded."""
        return _iter_messages(Path(self.path), wanted, damage=self.log)

    def add_pose(self, series: PoseBuffer, topic: str, stamp_ns: int, T: Any) -> None:
        """Buffer a robot pose; one that is not finite or not rigid is recorded as a bad
        message instead."""
        if T is None or not np.all(np.isfinite(T)):
            self.log.bad_message(topic, stamp_ns, "robot pose is not finite (NaN or inf)")
            return
        try:
            series.add(stamp_ns, T)
        except InputError as exc:
            self.log.bad_message(topic, stamp_ns, str(exc))


def _views(bag: _Bag, image_topic: str | None, right_image_topic: str | None,
           stereo: bool | None) -> dict[str, str]:
    """The image topic of each view (``image`` mono; ``left`` and ``right`` stereo): see
    :func:`read_bag_samples`."""
    source = bag.source
    images = [t for t, ti in bag.topics.items() if ti.msgtype == "sensor_msgs/msg/Image"]
    if image_topic is None:
        lefts = [t for t in images if "left" in t.split("/")]
        if len(images) == 1:
            image_topic = images[0]
        elif len(lefts) == 1:
            image_topic = lefts[0]
        else:
            raise ConfigError(f"{source}: give the image topic (image topics: "
                              f"{', '.join(images) or 'none'})")
    left_topic = _resolve_topic(bag.topics, image_topic, "image", bag.source)
    right_topic = None
    if stereo is not False:
        if right_image_topic is not None:
            right_topic = _resolve_topic(bag.topics, right_image_topic, "right image", bag.source)
        elif "left" in left_topic:
            candidate = left_topic.replace("left", "right")
            right_topic = candidate if candidate in bag.topics else None
        if stereo and right_topic is None:
            raise ConfigError(f"{source}: stereo requested but no right image topic found")
    views = {"left": left_topic, "right": right_topic} if right_topic else {"image": left_topic}
    return views


def _robot_poses(bag: _Bag, pose_topic: str | None, joint_topic: str | None,
                 kinematics: Any, use_tf: bool, base_frame: str, ee_frame: str,
                 tf_topic: str, tf_static_topic: str) -> tuple[PoseBuffer, str]:
    """Every robot pose of the bag from its source (see :func:`read_bag_samples`), and the
    source's description."""
    source = bag.source
    if pose_topic is None and joint_topic is None and not use_tf:
        if "/ee_pose" in bag.topics:
            pose_topic = "/ee_pose"
        elif tf_topic in bag.topics:
            use_tf = True
        else:
            raise ConfigError(f"{source}: no robot pose source (no /ee_pose, no /tf): give "
                              "--robot-pose ee_pose --ee-pose-topic T, --robot-pose "
                              "joint_states with --kinematics, or --robot-pose tf")
    if pose_topic is not None:
        pt = _resolve_topic(bag.topics, pose_topic, "pose", bag.source)
        pose_source = f"{pt} (PoseStamped)"
        series = _robot_series(bag.topics, pt)
        for topic, msgtype, log_ns, raw in bag.messages([pt]):
            try:
                msg = deserialize(raw, msgtype, bag.store)
                stamp, T = header_stamp_ns(msg), pose_to_matrix(msg)
            except _UNUSABLE as exc:
                bag.log.bad_message(topic, log_ns, str(exc))
                continue
            bag.add_pose(series, topic, stamp, T)
    elif joint_topic is not None:
        if kinematics is None:
            raise ConfigError("--robot-pose joint_states needs --kinematics (a kinematic "
                              "chain)")
        jt = _resolve_topic(bag.topics, joint_topic, "joint state", bag.source)
        pose_source = f"{jt} (JointState) + forward kinematics"
        # local: core.kinematics loads SciPy, needed with joint_states only
        from eye_in_hand.core.kinematics import JointIndex, MissingJointsError

        joints = JointIndex(kinematics.joint_names)
        series = _robot_series(bag.topics, jt)
        for topic, msgtype, log_ns, raw in bag.messages([jt]):
            try:
                msg = deserialize(raw, msgtype, bag.store)
            except _UNUSABLE as exc:
                bag.log.bad_message(topic, log_ns, str(exc))
                continue
            try:
                q = joints.positions(msg.name, msg.position)
            except MissingJointsError as exc:
                raise ConfigError(f"{source}: {jt}: {exc}, which the kinematic chain "
                                  "needs") from exc
            except InputError as exc:
                bag.log.bad_message(topic, header_stamp_ns(msg), str(exc))
                continue
            bag.add_pose(series, topic, header_stamp_ns(msg), kinematics.fk(q))
    else:
        pose_source = f"{tf_topic} {base_frame} -> {ee_frame}"
        tf = TfBuffer(max(2, bag.topics[tf_topic].count if tf_topic in bag.topics else 0))
        stamps_by_child: dict[str, list[int]] = {}
        for topic, msgtype, log_ns, raw in bag.messages([tf_topic, tf_static_topic]):
            try:
                msg = deserialize(raw, msgtype, bag.store)
            except _UNUSABLE as exc:
                bag.log.bad_message(topic, log_ns, str(exc))
                continue
            for tr in msg.transforms:
                key = (tr.header.frame_id.lstrip("/"), tr.child_frame_id.lstrip("/"))
                try:
                    stamp = header_stamp_ns(tr)
                    tf.set_transform(key[0], key[1], stamp, transform_to_matrix(tr),
                                     static=topic == tf_static_topic)
                except _UNUSABLE as exc:
                    bag.log.bad_message(topic, log_ns, f"{key[0]} -> {key[1]}: {exc}")
                    continue
                if topic != tf_static_topic:
                    stamps_by_child.setdefault(key[1], []).append(stamp)
        series = _tf_series(tf, stamps_by_child, base_frame, ee_frame, bag.source)
    if not len(series):
        raise ConfigError(f"{source}: no robot poses from {pose_source}")
    return series, pose_source


def _stops(stamps: list[int], series: PoseBuffer, still_window_s: float,
           still_translation_m: float, still_rotation_deg: float
           ) -> tuple[dict[int, tuple[str, np.ndarray]], list[dict[str, Any]]]:
    """The still robot stops among the image ``stamps`` (sorted): the chosen (middle) image
    stamp of each stop with its name and robot pose, and the images not used and why."""
    half = int(round(still_window_s * 0.5e9))
    first, last = series.oldest_ns or 0, series.newest_ns or 0     # the series is not empty
    skipped: list[dict[str, Any]] = []
    groups: list[list[tuple[int, np.ndarray]]] = []
    current: list[tuple[int, np.ndarray]] = []
    rot_tol = np.radians(still_rotation_deg)

    def close(Ta: np.ndarray, Tb: np.ndarray) -> bool:
        dt = float(np.linalg.norm(Ta[:3, 3] - Tb[:3, 3]))
        c = np.clip((np.trace(Ta[:3, :3].T @ Tb[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
        return dt <= still_translation_m and float(np.arccos(c)) <= rot_tol

    for stamp in stamps:
        at = _pose_at(series, stamp)
        reason = ""
        if at is None:
            reason = "no robot pose at the image stamp (outside the robot's time range)"
        elif first > stamp - half or last < stamp + half:
            reason = "robot poses do not cover the stillness window"
        elif not all(close(at, P) for P in series.between(stamp - half, stamp + half)):
            reason = "robot moving"
        if reason:
            skipped.append({"stamp_ns": stamp, "reason": reason})
            if current:
                groups.append(current)
                current = []
            continue
        assert at is not None
        if current and not close(current[0][1], at):
            groups.append(current)
            current = []
        current.append((stamp, at))
    if current:
        groups.append(current)
    chosen = {g[len(g) // 2][0]: (f"stop{k:03d}", g[len(g) // 2][1])
              for k, g in enumerate(groups)}
    return chosen, skipped


def _decode(bag: _Bag, views: Mapping[str, str], chosen: Mapping[int, Any]
            ) -> tuple[dict[int, dict[str, np.ndarray]], dict[str, Any], dict[str, np.ndarray],
                       dict[int, str]]:
    """Pass 2: the chosen images decoded per view, the first camera_info of each view, the
    simulator's ground truth when the bag has it, and why a chosen image could not be used."""
    bad_images: dict[int, str] = {}
    decoded: dict[int, dict[str, np.ndarray]] = {s: {} for s in chosen}
    infos: dict[str, Any] = {}
    info_topics = {_info_topic(t): v for v, t in views.items() if _info_topic(t) in bag.topics}
    truth: dict[str, np.ndarray] = {}
    wanted = list(views.values()) + list(info_topics)
    if "/ground_truth/hand_eye" in bag.topics:
        wanted.append("/ground_truth/hand_eye")
    topic_view = {t: v for v, t in views.items()}
    for topic, msgtype, log_ns, raw in bag.messages(wanted):
        try:
            if topic in info_topics:
                if info_topics[topic] not in infos:
                    infos[info_topics[topic]] = deserialize(raw, msgtype, bag.store)
                continue
            if topic == "/ground_truth/hand_eye":
                truth["ee_T_cam"] = transform_to_matrix(deserialize(raw, msgtype, bag.store))
                continue
            stamp = _cdr_header_stamp_ns(raw)
        except _UNUSABLE as exc:
            bag.log.bad_message(topic, log_ns, str(exc))
            continue
        if stamp in decoded:
            try:
                msg = deserialize(raw, msgtype, bag.store)
                img = calibration_image(msg)
            except _UNUSABLE as exc:
                bag.log.bad_message(topic, stamp, str(exc))
                bad_images[stamp] = f"the {topic_view[topic]} image at {stamp} ns is damaged " \
                    f"({exc})"
                continue
            decoded[stamp][topic_view[topic]] = img
    return decoded, infos, truth, bad_images


def _image_stamps(bag: _Bag, topic: str) -> list[int]:
    """The header stamps of ``topic``'s images, sorted (pass 1: headers only); an image
    without a readable one recorded in the bag's damage log."""
    stamps: list[int] = []
    for msg_topic, _msgtype, log_ns, raw in bag.messages([topic]):
        try:
            stamps.append(_cdr_header_stamp_ns(raw))
        except _UNUSABLE as exc:
            bag.log.bad_message(msg_topic, log_ns, str(exc))
    stamps.sort()
    return stamps


def _cameras(infos: Mapping[str, Any], views: Mapping[str, str], source: str
             ) -> tuple[CameraModel | None, StereoRig | None]:
    """The camera (mono) or the rig (stereo) of the views' camera_info, when every view has
    one."""
    camera = rig = None
    if set(infos) == set(views):
        if "image" in views:
            camera = camera_info_to_model(infos["image"], name="camera")
        else:
            left = camera_info_to_model(infos["left"], name="left")
            right = camera_info_to_model(infos["right"], name="right")
            rig = StereoRig.from_ros_pair(left, right, source=f"{source}: camera_info")
    return camera, rig


def read_bag_samples(path: str | os.PathLike[str], *, image_topic: str | None = None,
                     right_image_topic: str | None = None, pose_topic: str | None = None,
                     joint_topic: str | None = None, kinematics: Any = None,
                     use_tf: bool = False, base_frame: str = "base_link",
                     ee_frame: str = "tool0", stereo: bool | None = None,
                     still_window_s: float = 0.1, still_translation_m: float = 0.0005,
                     still_rotation_deg: float = 0.05, damage: Any = None,
                     tf_topic: str = "/tf", tf_static_topic: str = "/tf_static") -> BagSamples:
    """Find the still robot stops of a calibration recording and their images and poses.

    Each image (header stamp) is paired with the robot pose interpolated at that stamp (never
    extrapolated). An image is used only when the robot is still around it: every robot pose
    within ``still_window_s`` centred on the stamp is within ``still_translation_m`` and
    ``still_rotation_deg`` of the interpolated pose, and robot poses exist on both sides of the
    window. Consecutive still images at the same stop form one sample (its middle image).

    Args:
        path: the bag.
        image_topic: (left) image topic; a suffix such as ``left/image_raw`` matches an
            absolute topic. Default: the only image topic, or the one with ``left`` in its name.
        right_image_topic: right image topic (stereo). Default: the left topic with ``left``
            replaced by ``right`` when the bag has it and ``stereo`` is not False.
        pose_topic: ``geometry_msgs/PoseStamped`` robot pose topic (``base_T_ee``).
        joint_topic: ``sensor_msgs/JointState`` topic; needs ``kinematics``.
        kinematics: an object with ``fk(q) -> base_T_ee`` and ``joint_names``.
        use_tf: take the pose from ``tf_topic`` (+ ``tf_static_topic``), ``base_frame`` to
            ``ee_frame``.
        base_frame, ee_frame: frames of the /tf chain.
        stereo: force mono (False) or stereo (True); None: stereo when a right topic exists.
        still_window_s, still_translation_m, still_rotation_deg: the stillness test.
        damage: a :class:`eye_in_hand.io.bags.DamageLog` to record damage in (default: a new
            one, returned in ``BagSamples.damage``). Damaged chunks of the bag, messages that
            do not decode, truncated images and non-finite robot poses are skipped and
            recorded (topic, stamp, reason); the rest of the bag is used.

    Default pose source: ``pose_topic`` if given, else the joints, else /tf when asked, else
    ``/ee_pose`` when the bag has it, else ``/tf``.

    Returns:
        The samples (images decoded to numpy), cameras from camera_info when present.

    Raises:
        ConfigError: missing or ambiguous topics, no pose source, broken /tf chain.
        BagError: unreadable bag.
    """
    bag = _Bag(path, bag_info(Path(path)).topics, typestore_for(Path(path)),
               damage if damage is not None else DamageLog())
    source, log = bag.source, bag.log
    views = _views(bag, image_topic, right_image_topic, stereo)
    left_topic = views.get("left", views.get("image", ""))
    series, pose_source = _robot_poses(bag, pose_topic, joint_topic, kinematics, use_tf,
                                       base_frame, ee_frame, tf_topic, tf_static_topic)

    # Image stamps of the reference view (pass 1), stillness and grouping.
    stamps = _image_stamps(bag, left_topic)
    chosen, skipped = _stops(stamps, series, still_window_s, still_translation_m,
                             still_rotation_deg)
    decoded, infos, truth, bad_images = _decode(bag, views, chosen)
    samples = []
    for stamp in sorted(chosen):
        name, T = chosen[stamp]
        if set(decoded[stamp]) != set(views):
            missing = sorted(set(views) - set(decoded[stamp]))
            skipped.append({"stamp_ns": stamp, "name": name,
                            "reason": bad_images.get(
                                stamp, f"no {'/'.join(missing)} image with the same stamp")})
            continue
        samples.append(BagSample(name, stamp, decoded[stamp], T))
    camera, rig = _cameras(infos, views, source)
    return BagSamples(samples=tuple(samples), camera=camera, rig=rig, image_topics=views,
                      pose_source=pose_source, skipped=tuple(skipped), n_images=len(stamps),
                      ground_truth=truth, damage=log)

