"""Offline calibration datasets on disk (images + robot poses).

The hand-eye pose-pair files are :mod:`eye_in_hand.io.pose_pairs`, the calibration samples read
from a bag :mod:`eye_in_hand.io.bag_samples`.

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
"""
from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.core.transforms import as_transform, from_xyz_quat, to_xyz_quat
from eye_in_hand.errors import ConfigError, InputError
from eye_in_hand.io.images import write_image_file

__all__ = [
    "DatasetSample",
    "CalibrationDataset",
    "load_dataset",
    "write_dataset",
    "pose_to_dict",
    "pose_from_dict",
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
    for i, (imgs, T) in enumerate(zip(images, base_T_ee, strict=True)):
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
