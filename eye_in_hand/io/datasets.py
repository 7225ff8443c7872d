"""Offline calibration datasets on disk (images + robot poses), and hand-eye pose-pair files.

Dataset layout (``dataset.yaml``; paths are relative to the file's folder)::

    setup: eye_in_hand                # or eye_to_hand
    board: chessboard:9x6:0.025       # board spec string (type:colsxrows:square_m)
    left: left.yaml                   # camera_calibration_parsers YAML of a stereo rig ...
    right: right.yaml
    stereo: stereo.yaml               # optional: extrinsic R, T (else from the ROS P matrices)
    # camera: camera.yaml             # ... or one camera for a mono dataset
    samples:
      - left: left/0000.png           # mono: image: images/0000.png
        right: right/0000.png
        base_T_ee: {translation: [x, y, z], quat_xyzw: [x, y, z, w]}
        name: "0000"                  # optional (default: the image file stem)
    ground_truth:                     # optional, written by the simulator only
      ee_T_cam: {translation: [...], quat_xyzw: [...]}
      base_T_board: {translation: [...], quat_xyzw: [...]}

Pose-pairs file (no images): a JSON list of ``[base_T_ee, cam_T_board]`` pairs, each a 4x4
row-major nested list, metres (the format of MoveIt Calibration's test data).
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

import numpy as np
import yaml

from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.core.transforms import as_transform, from_xyz_quat, to_xyz_quat
from eye_in_hand.errors import ConfigError, InputError

__all__ = [
    "DatasetSample",
    "CalibrationDataset",
    "load_dataset",
    "write_dataset",
    "pose_to_dict",
    "pose_from_dict",
    "load_pose_pairs",
    "save_pose_pairs",
    "BagSample",
    "BagSamples",
    "read_bag_samples",
]

_SETUPS = ("eye_in_hand", "eye_to_hand")


@dataclass(frozen=True)
class DatasetSample:
    """One sample of a dataset.

    Attributes:
        name: sample name (``name`` key, else the first image's file stem).
        images: image paths by camera name (``left``/``right`` or ``image``), absolute.
        base_T_ee: robot pose, shape (4, 4).
    """

    name: str
    images: Mapping[str, Path]
    base_T_ee: np.ndarray


@dataclass(frozen=True)
class CalibrationDataset:
    """A calibration dataset read from ``dataset.yaml``.

    Attributes:
        root: the folder of ``dataset.yaml``.
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.
        board: board spec string.
        camera: the mono camera, or None for a stereo dataset.
        rig: the stereo rig, or None for a mono dataset.
        samples: the samples in file order.
        ground_truth: optional named transforms (``ee_T_cam``, ``base_T_board``...), (4, 4).
    """

    root: Path
    setup: str
    board: str
    camera: CameraModel | None
    rig: StereoRig | None
    samples: tuple[DatasetSample, ...]
    ground_truth: Mapping[str, np.ndarray] = field(default_factory=dict)

    @property
    def is_stereo(self) -> bool:
        """True for a stereo dataset."""
        return self.rig is not None

    @property
    def camera_names(self) -> tuple[str, ...]:
        """The image keys of every sample: ``("left", "right")`` or ``("image",)``."""
        return ("left", "right") if self.is_stereo else ("image",)


def pose_to_dict(T: np.ndarray) -> dict[str, list[float]]:
    """``{translation: [x, y, z], quat_xyzw: [x, y, z, w]}`` of a 4x4 transform."""
    t, q = to_xyz_quat(T)
    return {"translation": [float(v) for v in t], "quat_xyzw": [float(v) for v in q]}


def pose_from_dict(node: Any, where: str) -> np.ndarray:
    """4x4 transform from ``{translation, quat_xyzw}``.

    Args:
        node: the mapping.
        where: location for messages (file, sample, field).

    Raises:
        ConfigError: missing keys, wrong lengths, NaN, non-unit quaternion.
    """
    if not isinstance(node, Mapping):
        raise ConfigError(f"{where}: expected a mapping with translation and quat_xyzw")
    for key, n in (("translation", 3), ("quat_xyzw", 4)):
        if key not in node:
            raise ConfigError(f"{where}: missing '{key}'")
        value = node[key]
        if not isinstance(value, (list, tuple)) or len(value) != n:
            raise ConfigError(f"{where}.{key}: expected a list of {n} numbers, got {value!r}")
    try:
        t = np.asarray(node["translation"], dtype=np.float64)
        q = np.asarray(node["quat_xyzw"], dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: translation and quat_xyzw must be numbers") from exc
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(q))):
        raise ConfigError(f"{where}: contains NaN or infinite values")
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > 1e-4:
        raise ConfigError(f"{where}.quat_xyzw: not a unit quaternion (norm {norm:.6f}); "
                          "expected (x, y, z, w)")
    try:
        return from_xyz_quat(t, q / norm)
    except InputError as exc:
        raise ConfigError(f"{where}: {exc}") from exc


def _rel_file(root: Path, value: Any, where: str) -> Path:
    if not isinstance(value, str) or not value:
        raise ConfigError(f"{where}: expected a relative file path, got {value!r}")
    path = (root / value).resolve()
    if not path.is_file():
        raise ConfigError(f"{where}: file not found: {path}")
    return path


def _load_rig(root: Path, data: Mapping[str, Any], source: str) -> StereoRig:
    left = CameraModel.load_yaml(_rel_file(root, data.get("left"), f"{source}: left"))
    right = CameraModel.load_yaml(_rel_file(root, data.get("right"), f"{source}: right"))
    if data.get("stereo") is None:
        return StereoRig.from_ros_pair(left, right, source=f"{source}: right")
    return StereoRig.from_stereo_file(
        left, right, _rel_file(root, data["stereo"], f"{source}: stereo"))


def load_dataset(path: str | os.PathLike[str]) -> CalibrationDataset:
    """Read a calibration dataset.

    Args:
        path: the dataset folder (containing ``dataset.yaml``) or the YAML file itself.

    Returns:
        The dataset (images are not read; see :attr:`DatasetSample.images`).

    Raises:
        ConfigError: missing file, YAML error, missing or malformed keys, missing images or
            camera files, mixed mono/stereo samples; messages name the file, the sample index
            and the field.
    """
    p = Path(path)
    yaml_path = p / "dataset.yaml" if p.is_dir() else p
    if not yaml_path.is_file():
        raise ConfigError(f"{yaml_path}: dataset file not found")
    root = yaml_path.parent.resolve()
    source = str(yaml_path)
    try:
        data = yaml.safe_load(yaml_path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{source}: cannot read dataset ({exc})") from exc
    if not isinstance(data, Mapping):
        raise ConfigError(f"{source}: expected a mapping at the top level")
    setup = data.get("setup", "eye_in_hand")
    if setup not in _SETUPS:
        raise ConfigError(f"{source}: 'setup' must be one of {', '.join(_SETUPS)}, got {setup!r}")
    board = data.get("board")
    if not isinstance(board, str) or not board:
        raise ConfigError(f"{source}: missing 'board' (a spec such as chessboard:9x6:0.025)")
    stereo = "left" in data or "right" in data
    if stereo and "camera" in data:
        raise ConfigError(f"{source}: give either 'camera' (mono) or 'left'/'right' (stereo)")
    camera: CameraModel | None = None
    rig: StereoRig | None = None
    if stereo:
        rig = _load_rig(root, data, source)
    elif "camera" in data:
        camera = CameraModel.load_yaml(_rel_file(root, data["camera"], f"{source}: camera"))
    else:
        raise ConfigError(f"{source}: missing camera calibration ('camera', or 'left' + 'right')")
    raw = data.get("samples")
    if not isinstance(raw, list) or not raw:
        raise ConfigError(f"{source}: 'samples' must be a non-empty list")
    keys = ("left", "right") if stereo else ("image",)
    samples: list[DatasetSample] = []
    names: set[str] = set()
    for i, entry in enumerate(raw):
        where = f"{source}: samples[{i}]"
        if not isinstance(entry, Mapping):
            raise ConfigError(f"{where}: expected a mapping")
        other = ("image",) if stereo else ("left", "right")
        if any(k in entry for k in other):
            raise ConfigError(f"{where}: has {'/'.join(k for k in other if k in entry)} but the "
                              f"dataset is {'stereo' if stereo else 'mono'} (expected "
                              f"{' and '.join(keys)})")
        images = {}
        for key in keys:
            if key not in entry:
                raise ConfigError(f"{where}: missing '{key}' image")
            images[key] = _rel_file(root, entry[key], f"{where}.{key}")
        if "base_T_ee" not in entry:
            raise ConfigError(f"{where}: missing 'base_T_ee'")
        T = pose_from_dict(entry["base_T_ee"], f"{where}.base_T_ee")
        name = str(entry.get("name") or images[keys[0]].stem)
        if name in names:
            name = f"{name}#{i}"
        names.add(name)
        samples.append(DatasetSample(name=name, images=images, base_T_ee=T))
    truth: dict[str, np.ndarray] = {}
    gt = data.get("ground_truth")
    if gt is not None:
        if not isinstance(gt, Mapping):
            raise ConfigError(f"{source}: 'ground_truth' must be a mapping")
        for key, node in gt.items():
            truth[str(key)] = pose_from_dict(node, f"{source}: ground_truth.{key}")
    return CalibrationDataset(root=root, setup=setup, board=board, camera=camera, rig=rig,
                              samples=tuple(samples), ground_truth=truth)


def write_dataset(directory: str | os.PathLike[str], *, setup: str, board: str,
                  images: Sequence[Mapping[str, np.ndarray]], base_T_ee: Sequence[np.ndarray],
                  camera: CameraModel | None = None, rig: StereoRig | None = None,
                  ground_truth: Mapping[str, np.ndarray] | None = None,
                  names: Sequence[str] | None = None) -> Path:
    """Write a dataset (images as PNG under ``left/``, ``right/`` or ``images/``).

    Args:
        directory: output folder (created).
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.
        board: board spec string.
        images: per sample, images by camera key (``left``/``right`` or ``image``), uint8.
        base_T_ee: per sample robot pose, shape (4, 4).
        camera: the mono camera (exclusive with ``rig``).
        rig: the stereo rig; written as left.yaml, right.yaml (ROS, rectified) and stereo.yaml.
        ground_truth: optional named transforms.
        names: optional sample names (default ``0000``, ``0001``...).

    Returns:
        The path of ``dataset.yaml``.

    Raises:
        InputError: inconsistent arguments.
        ConfigError: files cannot be written.
    """
    from eye_in_hand.io.images import write_image_file

    if (camera is None) == (rig is None):
        raise InputError("write_dataset: give exactly one of camera (mono) or rig (stereo)")
    if len(images) != len(base_T_ee):
        raise InputError(f"write_dataset: {len(images)} image sets but {len(base_T_ee)} poses")
    if setup not in _SETUPS:
        raise InputError(f"write_dataset: setup must be one of {', '.join(_SETUPS)}")
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    data: dict[str, Any] = {"setup": setup, "board": board}
    if rig is not None:
        lp, rp, sp = rig.save(out)
        data.update({"left": lp.name, "right": rp.name, "stereo": sp.name})
        keys = {"left": "left", "right": "right"}
    else:
        assert camera is not None
        camera.save_yaml(out / "camera.yaml")
        data["camera"] = "camera.yaml"
        keys = {"image": "images"}
    samples = []
    for i, (imgs, T) in enumerate(zip(images, base_T_ee)):
        name = names[i] if names is not None else f"{i:04d}"
        entry: dict[str, Any] = {}
        for key, folder in keys.items():
            if key not in imgs:
                raise InputError(f"write_dataset: sample {i} has no '{key}' image")
            rel = f"{folder}/{name}.png"
            (out / folder).mkdir(exist_ok=True)
            write_image_file(out / rel, np.asarray(imgs[key]))
            entry[key] = rel
        entry["base_T_ee"] = pose_to_dict(as_transform(T, f"base_T_ee[{i}]"))
        if names is not None:
            entry["name"] = name
        samples.append(entry)
    data["samples"] = samples
    if ground_truth:
        data["ground_truth"] = {k: pose_to_dict(v) for k, v in ground_truth.items()}
    path = out / "dataset.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False, default_flow_style=None))
    return path


def load_pose_pairs(path: str | os.PathLike[str]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Read a pose-pairs JSON file: a list of ``[base_T_ee, cam_T_board]`` 4x4 pairs.

    Args:
        path: the JSON file.

    Returns:
        ``[(base_T_ee (4, 4), cam_T_board (4, 4)), ...]``.

    Raises:
        ConfigError: missing file, bad JSON, a pair with other than two matrices, or a matrix
            of the wrong shape, with NaN or a non-orthonormal rotation (naming the pair index).
    """
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise ConfigError(f"{p}: pose-pairs file not found") from exc
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{p}: cannot read pose pairs ({exc})") from exc
    if not isinstance(data, list) or not data:
        raise ConfigError(f"{p}: expected a non-empty JSON list of [base_T_ee, cam_T_board] pairs")
    out = []
    for i, pair in enumerate(data):
        if not isinstance(pair, list) or len(pair) != 2:
            n = len(pair) if isinstance(pair, list) else type(pair).__name__
            raise ConfigError(f"{p}: pair {i}: expected [base_T_ee, cam_T_board], got {n} "
                              "entries")
        mats = []
        for name, M in zip(("base_T_ee", "cam_T_board"), pair):
            try:
                mats.append(as_transform(np.asarray(M, dtype=np.float64), name))
            except (InputError, ValueError, TypeError) as exc:
                raise ConfigError(f"{p}: pair {i}: {exc}") from exc
        out.append((mats[0], mats[1]))
    return out


def save_pose_pairs(path: str | os.PathLike[str],
                    pairs: Sequence[tuple[np.ndarray, np.ndarray]]) -> Path:
    """Write pose pairs in the format :func:`load_pose_pairs` reads."""
    from eye_in_hand.io.atomic import atomic_write_text

    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(p, json.dumps([[np.asarray(a).tolist(), np.asarray(b).tolist()]
                                     for a, b in pairs]))
    return p


# -- calibration samples from a bag ---------------------------------------------------------

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


class _PoseSeries:
    """Stamped poses of one frame pair, interpolated at a stamp (never extrapolated)."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.stamps: list[int] = []
        self.poses: list[np.ndarray] = []

    def add(self, stamp_ns: int, T: np.ndarray) -> None:
        self.stamps.append(int(stamp_ns))
        self.poses.append(T)

    def finish(self) -> None:
        order = np.argsort(np.asarray(self.stamps, dtype=np.int64), kind="stable")
        self.stamps = [self.stamps[i] for i in order]
        self.poses = [self.poses[i] for i in order]

    def at(self, stamp_ns: int) -> np.ndarray | None:
        import bisect

        from eye_in_hand.core.transforms import interpolate

        if not self.stamps or stamp_ns < self.stamps[0] or stamp_ns > self.stamps[-1]:
            return None
        k = bisect.bisect_left(self.stamps, stamp_ns)
        if self.stamps[k] == stamp_ns:
            return self.poses[k]
        return interpolate(stamp_ns, self.stamps[k - 1], self.poses[k - 1], self.stamps[k],
                           self.poses[k])

    def window(self, lo_ns: int, hi_ns: int) -> list[np.ndarray]:
        import bisect

        a = bisect.bisect_left(self.stamps, lo_ns)
        b = bisect.bisect_right(self.stamps, hi_ns)
        return self.poses[a:b]


def _cdr_header_stamp_ns(raw: bytes) -> int:
    """The ``header.stamp`` of a CDR message whose first field is a ``std_msgs/Header``, read
    without decoding the rest (an image's pixels are not copied)."""
    import struct

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


def _tf_chain(edges: Mapping[tuple[str, str], _PoseSeries],
              static: Mapping[tuple[str, str], np.ndarray], base: str, tip: str,
              source: str) -> tuple[list[tuple[str, str]], tuple[str, str]]:
    parent_of = {c: p for (p, c) in list(edges) + list(static)}
    chain = []
    frame = tip
    while frame != base:
        if frame not in parent_of:
            raise ConfigError(f"{source}: /tf has no chain from {base!r} to {tip!r} (stuck at "
                              f"{frame!r})")
        chain.append((parent_of[frame], frame))
        frame = parent_of[frame]
        if len(chain) > 64:
            raise ConfigError(f"{source}: /tf has a loop between {base!r} and {tip!r}")
    chain.reverse()
    dynamic = [e for e in chain if e in edges]
    if not dynamic:
        raise ConfigError(f"{source}: the /tf chain {base!r} -> {tip!r} is static")
    return chain, dynamic[-1]


def read_bag_samples(path: str | os.PathLike[str], *, image_topic: str | None = None,
                     right_image_topic: str | None = None, pose_topic: str | None = None,
                     joint_topic: str | None = None, kinematics: Any = None,
                     use_tf: bool = False, base_frame: str = "base_link",
                     ee_frame: str = "tool0", stereo: bool | None = None,
                     still_window_s: float = 0.1, still_translation_m: float = 0.0005,
                     still_rotation_deg: float = 0.05, damage: Any = None) -> BagSamples:
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
        use_tf: take the pose from ``/tf`` (+ ``/tf_static``), ``base_frame`` to ``ee_frame``.
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
    from eye_in_hand.errors import BagError, ConversionError
    from eye_in_hand.io.bags import DamageLog, bag_info, deserialize, typestore_for
    from eye_in_hand.io.bags import iter_messages as _iter_messages
    from eye_in_hand.ros.conversions import (camera_info_to_model, header_stamp_ns,
                                             image_to_numpy, pose_to_matrix,
                                             transform_to_matrix)

    source = str(path)
    info = bag_info(path)
    topics = info.topics
    store = typestore_for(path)
    log = damage if damage is not None else DamageLog()
    unusable = (BagError, ConversionError, InputError, ConfigError, ValueError)
    bad_images: dict[int, str] = {}

    def iter_messages(bag: Any, wanted: list[str]) -> Iterator[tuple[str, str, int, Any]]:
        """The bag's messages, damaged parts skipped and recorded."""
        return _iter_messages(bag, wanted, damage=log)

    def usable(topic: str, stamp_ns: int, T: Any) -> bool:
        """Whether a robot pose is finite (else it is recorded as a bad message)."""
        if T is not None and np.all(np.isfinite(T)):
            return True
        log.bad_message(topic, stamp_ns, "robot pose is not finite (NaN or inf)")
        return False
    images = [t for t, ti in topics.items() if ti.msgtype == "sensor_msgs/msg/Image"]
    if image_topic is None:
        lefts = [t for t in images if "left" in t.split("/")]
        if len(images) == 1:
            image_topic = images[0]
        elif len(lefts) == 1:
            image_topic = lefts[0]
        else:
            raise ConfigError(f"{source}: give the image topic (image topics: "
                              f"{', '.join(images) or 'none'})")
    left_topic = _resolve_topic(topics, image_topic, "image", source)
    right_topic = None
    if stereo is not False:
        if right_image_topic is not None:
            right_topic = _resolve_topic(topics, right_image_topic, "right image", source)
        elif "left" in left_topic:
            candidate = left_topic.replace("left", "right")
            right_topic = candidate if candidate in topics else None
        if stereo and right_topic is None:
            raise ConfigError(f"{source}: stereo requested but no right image topic found")
    views = {"left": left_topic, "right": right_topic} if right_topic else {"image": left_topic}

    # Robot pose source.
    series = _PoseSeries("robot")
    if pose_topic is None and joint_topic is None and not use_tf:
        if "/ee_pose" in topics:
            pose_topic = "/ee_pose"
        elif "/tf" in topics:
            use_tf = True
        else:
            raise ConfigError(f"{source}: no robot pose source: give --pose-topic, "
                              "--joint-topic with --kinematics, or --tf")
    if pose_topic is not None:
        pt = _resolve_topic(topics, pose_topic, "pose", source)
        pose_source = f"{pt} (PoseStamped)"
        for topic, msgtype, log_ns, raw in iter_messages(path, [pt]):
            try:
                msg = deserialize(raw, msgtype, store)
                stamp, T = header_stamp_ns(msg), pose_to_matrix(msg)
            except unusable as exc:
                log.bad_message(topic, log_ns, str(exc))
                continue
            if usable(topic, stamp, T):
                series.add(stamp, T)
    elif joint_topic is not None:
        if kinematics is None:
            raise ConfigError("--joint-topic needs --kinematics (a DH chain)")
        jt = _resolve_topic(topics, joint_topic, "joint state", source)
        pose_source = f"{jt} (JointState) + forward kinematics"
        names = list(kinematics.joint_names)
        for topic, msgtype, log_ns, raw in iter_messages(path, [jt]):
            try:
                msg = deserialize(raw, msgtype, store)
            except unusable as exc:
                log.bad_message(topic, log_ns, str(exc))
                continue
            pos = dict(zip(list(msg.name), np.asarray(msg.position, dtype=float)))
            missing = [n for n in names if n not in pos]
            if missing:
                raise ConfigError(f"{source}: {jt} lacks joints {missing} of the kinematic "
                                  "chain")
            q = [pos[n] for n in names]
            if not np.all(np.isfinite(q)):
                log.bad_message(topic, header_stamp_ns(msg), "joint positions are not finite")
                continue
            series.add(header_stamp_ns(msg), kinematics.fk(q))
    else:
        pose_source = f"/tf {base_frame} -> {ee_frame}"
        edges: dict[tuple[str, str], _PoseSeries] = {}
        static: dict[tuple[str, str], np.ndarray] = {}
        for topic, msgtype, log_ns, raw in iter_messages(path, ["/tf", "/tf_static"]):
            try:
                msg = deserialize(raw, msgtype, store)
            except unusable as exc:
                log.bad_message(topic, log_ns, str(exc))
                continue
            for tr in msg.transforms:
                key = (tr.header.frame_id.lstrip("/"), tr.child_frame_id.lstrip("/"))
                try:
                    T = transform_to_matrix(tr)
                except unusable as exc:
                    log.bad_message(topic, log_ns, f"{key[0]} -> {key[1]}: {exc}")
                    continue
                if topic == "/tf_static":
                    static[key] = T
                else:
                    edges.setdefault(key, _PoseSeries(f"{key[0]}->{key[1]}")).add(
                        header_stamp_ns(tr), T)
        for s in edges.values():
            s.finish()
        chain, clock = _tf_chain(edges, static, base_frame, ee_frame, source)
        for stamp in edges[clock].stamps:
            T = np.eye(4)
            for e in chain:
                part = static[e] if e not in edges else edges[e].at(stamp)
                if part is None:
                    T = None
                    break
                T = T @ part
            if T is not None:
                series.add(stamp, T)
    series.finish()
    if not series.stamps:
        raise ConfigError(f"{source}: no robot poses from {pose_source}")

    # Image stamps of the reference view (pass 1), stillness and grouping.
    stamps: list[int] = []
    for topic, msgtype, log_ns, raw in iter_messages(path, [left_topic]):
        try:
            stamps.append(_cdr_header_stamp_ns(raw))
        except unusable as exc:
            log.bad_message(topic, log_ns, str(exc))
    stamps.sort()
    half = int(round(still_window_s * 0.5e9))
    skipped: list[dict[str, Any]] = []
    groups: list[list[tuple[int, np.ndarray]]] = []
    current: list[tuple[int, np.ndarray]] = []
    rot_tol = np.radians(still_rotation_deg)

    def close(Ta: np.ndarray, Tb: np.ndarray) -> bool:
        dt = float(np.linalg.norm(Ta[:3, 3] - Tb[:3, 3]))
        c = np.clip((np.trace(Ta[:3, :3].T @ Tb[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
        return dt <= still_translation_m and float(np.arccos(c)) <= rot_tol

    for stamp in stamps:
        T = series.at(stamp)
        reason = ""
        if T is None:
            reason = "no robot pose at the image stamp (outside the robot's time range)"
        elif series.stamps[0] > stamp - half or series.stamps[-1] < stamp + half:
            reason = "robot poses do not cover the stillness window"
        elif not all(close(T, P) for P in series.window(stamp - half, stamp + half)):
            reason = "robot moving"
        if reason:
            skipped.append({"stamp_ns": stamp, "reason": reason})
            if current:
                groups.append(current)
                current = []
            continue
        assert T is not None
        if current and not close(current[0][1], T):
            groups.append(current)
            current = []
        current.append((stamp, T))
    if current:
        groups.append(current)
    chosen = {g[len(g) // 2][0]: (f"stop{k:03d}", g[len(g) // 2][1])
              for k, g in enumerate(groups)}

    # Pass 2: decode the chosen images (and the first camera_info of each view).
    decoded: dict[int, dict[str, np.ndarray]] = {s: {} for s in chosen}
    infos: dict[str, Any] = {}
    info_topics = {_info_topic(t): v for v, t in views.items() if _info_topic(t) in topics}
    truth: dict[str, np.ndarray] = {}
    wanted = list(views.values()) + list(info_topics)
    if "/ground_truth/hand_eye" in topics:
        wanted.append("/ground_truth/hand_eye")
    topic_view = {t: v for v, t in views.items()}
    for topic, msgtype, log_ns, raw in iter_messages(path, wanted):
        try:
            if topic in info_topics:
                if info_topics[topic] not in infos:
                    infos[info_topics[topic]] = deserialize(raw, msgtype, store)
                continue
            if topic == "/ground_truth/hand_eye":
                truth["ee_T_cam"] = transform_to_matrix(deserialize(raw, msgtype, store))
                continue
            stamp = _cdr_header_stamp_ns(raw)
        except unusable as exc:
            log.bad_message(topic, log_ns, str(exc))
            continue
        if stamp in decoded:
            try:
                msg = deserialize(raw, msgtype, store)
                img = image_to_numpy(msg, copy=True)
            except unusable as exc:
                log.bad_message(topic, stamp, str(exc))
                bad_images[stamp] = f"the {topic_view[topic]} image at {stamp} ns is damaged " \
                    f"({exc})"
                continue
            enc = str(msg.encoding).lower()
            if enc == "rgb8":
                img = img[..., ::-1].copy()
            decoded[stamp][topic_view[topic]] = img
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
    camera = rig = None
    if set(infos) == set(views):
        if "image" in views:
            camera = camera_info_to_model(infos["image"], name="camera")
        else:
            left = camera_info_to_model(infos["left"], name="left")
            right = camera_info_to_model(infos["right"], name="right")
            rig = StereoRig.from_ros_pair(left, right, source=f"{source}: camera_info")
    return BagSamples(samples=tuple(samples), camera=camera, rig=rig, image_topics=views,
                      pose_source=pose_source, skipped=tuple(skipped), n_images=len(stamps),
                      ground_truth=truth, damage=log)
