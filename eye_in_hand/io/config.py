"""Hand-eye calibration files (``hand_eye.yaml``): write, read, validate.

Format (YAML, safe_load; every length in metres, angles in radians)::

    setup: eye_in_hand                 # or eye_to_hand
    parent_frame: tool0                # X = parent_T_child: tool0 (eye_in_hand) or base_link
    child_frame: camera_left_optical_frame
    translation: [x, y, z]             # of child in parent
    quat_xyzw: [x, y, z, w]            # unit quaternion, ROS order
    method: refined                    # the solver that produced it
    covariance:                        # optional 6x6, row-major list of 6 rows, order
      - [...]                          #   x y z rx ry rz: translation (m^2) and a rotation
                                       #   vector (rad^2) applied on the left, R' = exp([dr]x) R
    sample_count: 15
    residuals:                         # optional summary figures, free-form numbers
      axxb_rot_deg_rms: 0.01
      ...
    stamp: "2026-01-01T00:00:00Z"      # optional, when it was computed
    robot_pose_noise:                  # optional: the robot-pose noise the calibration
      translation_sigma_m: 0.0002      #   estimated (1 sigma per axis, flange frame)
      rotation_sigma_rad: 0.0003
    robot_pose_correction:             # optional (eye_in_hand): the systematic robot error
      model: flange_orientation_linear #   model's correction; X holds with the robot poses
      reference_quat_xyzw: [x, y, z, w]  #   corrected by it (core.pose_correction):
      rotation_rad_per_rad: [[...], [...], [...]]   # A_r, 3x3
      translation_m_per_rad: [[...], [...], [...]]  # A_t, 3x3

``translation`` and ``quat_xyzw`` sit at the top level so that other tools can read the file
without knowing the rest.
"""
from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from eye_in_hand.core.pose_correction import MODEL as CORRECTION_MODEL
from eye_in_hand.core.pose_correction import RobotPoseCorrection
from eye_in_hand.core.transforms import from_xyz_quat, matrix_to_quat_xyzw, to_xyz_quat
from eye_in_hand.errors import ConfigError, InputError
from eye_in_hand.yamlfile import read_yaml_file

__all__ = [
    "HandEyeCalibration",
    "save_hand_eye",
    "load_hand_eye",
    "hand_eye_from_dict",
    "COVARIANCE_ORDER",
]

#: The order of the covariance's rows and columns.
COVARIANCE_ORDER = ("x", "y", "z", "rx", "ry", "rz")

_SETUPS = ("eye_in_hand", "eye_to_hand")
_NOISE_KEYS = ("translation_sigma_m", "rotation_sigma_rad")
_QUAT_NORM_TOL = 1e-6


@dataclass(frozen=True)
class HandEyeCalibration:
    """A hand-eye calibration as stored in ``hand_eye.yaml``.

    Attributes:
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.
        parent_frame: frame id of the parent (``tool0`` eye-in-hand, ``base_link`` eye-to-hand).
        child_frame: frame id of the camera (``camera_left_optical_frame``).
        transform: ``parent_T_child``, shape (4, 4).
        method: the solver that produced it.
        covariance: shape (6, 6) in :data:`COVARIANCE_ORDER`, or None.
        sample_count: number of samples used.
        residuals: summary residual figures (name -> number or None).
        stamp: free-form time stamp text ('' when absent).
        robot_pose_noise: the estimated robot-pose noise, ``{"translation_sigma_m": float,
            "rotation_sigma_rad": float}`` (1 sigma per axis, flange frame), or None (files
            written before it existed, or without the errors-in-variables refinement).
        robot_pose_correction: the systematic robot error model's correction of the reported
            flange poses (:class:`~eye_in_hand.core.pose_correction.RobotPoseCorrection`),
            written when ``refined_systematic`` was selected: ``transform`` holds with the
            corrected poses. None: use the reported poses as they are.
    """

    setup: str
    parent_frame: str
    child_frame: str
    transform: np.ndarray
    method: str = "unknown"
    covariance: np.ndarray | None = None
    sample_count: int = 0
    residuals: Mapping[str, float | None] = field(default_factory=dict)
    stamp: str = ""
    robot_pose_noise: Mapping[str, float] | None = None
    robot_pose_correction: RobotPoseCorrection | None = None

    @property
    def translation(self) -> np.ndarray:
        """Translation of the child in the parent frame, shape (3,), metres."""
        return self.transform[:3, 3].copy()

    @property
    def quat_xyzw(self) -> np.ndarray:
        """Rotation as a unit quaternion (x, y, z, w), w >= 0."""
        return to_xyz_quat(self.transform)[1]

    def to_dict(self) -> dict[str, Any]:
        """The YAML mapping."""
        t, q = to_xyz_quat(self.transform)
        out: dict[str, Any] = {
            "setup": self.setup,
            "parent_frame": self.parent_frame,
            "child_frame": self.child_frame,
            "translation": [float(v) for v in t],
            "quat_xyzw": [float(v) for v in q],
            "method": self.method,
            "covariance": None if self.covariance is None else
            [[float(v) for v in row] for row in self.covariance],
            "covariance_order": list(COVARIANCE_ORDER),
            "sample_count": int(self.sample_count),
            "residuals": {str(k): (None if v is None else float(v))
                          for k, v in self.residuals.items()},
        }
        if self.stamp:
            out["stamp"] = self.stamp
        if self.robot_pose_noise is not None:
            out["robot_pose_noise"] = {k: float(v) for k, v in self.robot_pose_noise.items()}
        c = self.robot_pose_correction
        if c is not None:
            out["robot_pose_correction"] = {
                "model": CORRECTION_MODEL,
                "reference_quat_xyzw": [float(v) for v in matrix_to_quat_xyzw(c.R_ref)],
                "rotation_rad_per_rad": [[float(v) for v in row] for row in c.A_r],
                "translation_m_per_rad": [[float(v) for v in row] for row in c.A_t]}
        return out


def _fail(source: str, message: str) -> ConfigError:
    return ConfigError(f"{source}: {message}")


def _vector(data: Mapping[str, Any], key: str, n: int, source: str) -> np.ndarray:
    if key not in data:
        raise _fail(source, f"missing key '{key}'")
    try:
        arr = np.asarray(data[key], dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise _fail(source, f"'{key}' must be a list of {n} numbers") from exc
    if arr.shape != (n,):
        raise _fail(source, f"'{key}' must be a list of {n} numbers, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise _fail(source, f"'{key}' contains NaN or infinite values")
    return arr


def hand_eye_from_dict(data: Any, source: str = "<hand_eye>") -> HandEyeCalibration:
    """Build and validate a :class:`HandEyeCalibration` from its YAML mapping.

    Args:
        data: the parsed YAML.
        source: file name for messages.

    Returns:
        The calibration.

    Raises:
        ConfigError: missing keys, wrong shapes, non-unit quaternion, NaN, bad setup or
            covariance; the message names ``source`` and the key.
    """
    if not isinstance(data, Mapping):
        raise _fail(source, f"expected a mapping at the top level, got {type(data).__name__}")
    setup = data.get("setup")
    if setup not in _SETUPS:
        raise _fail(source, f"'setup' must be one of {', '.join(_SETUPS)}, got {setup!r}")
    frames = []
    for key in ("parent_frame", "child_frame"):
        value = data.get(key)
        if not isinstance(value, str) or not value:
            raise _fail(source, f"missing or empty key '{key}'")
        frames.append(value)
    T = _transform(data, source)
    cov = _covariance(data.get("covariance"), source)
    order = data.get("covariance_order")
    if order is not None and list(order) != list(COVARIANCE_ORDER):
        raise _fail(source, f"'covariance_order' must be {list(COVARIANCE_ORDER)}, got {order}")
    count = data.get("sample_count", 0)
    if isinstance(count, bool) or not isinstance(count, int) or count < 0:
        raise _fail(source, f"'sample_count' must be a non-negative integer, got {count!r}")
    clean = _residuals(data.get("residuals") or {}, source)
    method = data.get("method", "unknown")
    if not isinstance(method, str):
        raise _fail(source, f"'method' must be text, got {method!r}")
    noise = _noise(data.get("robot_pose_noise"), source)
    correction = _correction(data.get("robot_pose_correction"), source)
    if correction is not None and setup != "eye_in_hand":
        raise _fail(source, "'robot_pose_correction' is for eye_in_hand calibrations (an "
                            "eye-to-hand localization uses no robot pose); remove the block")
    return HandEyeCalibration(setup=setup, parent_frame=frames[0], child_frame=frames[1],
                              transform=T, method=method, covariance=cov,
                              sample_count=count, residuals=clean,
                              stamp=str(data.get("stamp", "") or ""), robot_pose_noise=noise,
                              robot_pose_correction=correction)


def _transform(data: Mapping[str, Any], source: str) -> np.ndarray:
    """The 4x4 transform of ``translation`` and ``quat_xyzw`` (a unit quaternion)."""
    t = _vector(data, "translation", 3, source)
    q = _vector(data, "quat_xyzw", 4, source)
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > _QUAT_NORM_TOL:
        raise _fail(source, f"'quat_xyzw' is not a unit quaternion (norm {norm:.9f}); "
                            "expected (x, y, z, w) with norm 1")
    try:
        return from_xyz_quat(t, q / norm)
    except InputError as exc:
        raise _fail(source, str(exc)) from exc


def _covariance(value: Any, source: str) -> np.ndarray | None:
    """``covariance``: None, or a finite, symmetric, positive semi-definite 6x6 matrix (36
    numbers in a row are taken row by row)."""
    if value is None:
        return None
    try:
        cov = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise _fail(source, "'covariance' must be a 6x6 list of numbers") from exc
    if cov.shape == (36,):
        cov = cov.reshape(6, 6)
    if cov.shape != (6, 6):
        raise _fail(source, f"'covariance' must be 6x6, got shape {cov.shape}")
    if not np.all(np.isfinite(cov)):
        raise _fail(source, "'covariance' contains NaN or infinite values")
    if np.max(np.abs(cov - cov.T)) > 1e-9 * max(1.0, float(np.max(np.abs(cov)))):
        raise _fail(source, "'covariance' is not symmetric")
    if np.min(np.linalg.eigvalsh(cov)) < -1e-12 * max(1.0, float(np.max(np.abs(cov)))):
        raise _fail(source, "'covariance' is not positive semi-definite")
    return cov


def _residuals(residuals: Any, source: str) -> dict[str, float | None]:
    """``residuals``: names to finite numbers (or null)."""
    if not isinstance(residuals, Mapping):
        raise _fail(source, "'residuals' must be a mapping of names to numbers")
    clean: dict[str, float | None] = {}
    for k, v in residuals.items():
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))
                              or not math.isfinite(float(v))):
            raise _fail(source, f"residuals.{k}: expected a finite number or null, got {v!r}")
        clean[str(k)] = None if v is None else float(v)
    return clean


def _noise(noise: Any, source: str) -> dict[str, float] | None:
    """``robot_pose_noise``: None, or both sigmas as finite numbers >= 0."""
    if noise is None:
        return None
    if not isinstance(noise, Mapping) or set(noise) != set(_NOISE_KEYS):
        raise _fail(source, "'robot_pose_noise' must be a mapping with "
                            f"{', '.join(_NOISE_KEYS)}, got {noise!r}")
    for k in _NOISE_KEYS:
        v = noise[k]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                or v < 0:
            raise _fail(source, f"robot_pose_noise.{k}: expected a finite number >= 0, got "
                                f"{v!r}")
    return {k: float(noise[k]) for k in _NOISE_KEYS}


_CORRECTION_KEYS = ("model", "reference_quat_xyzw", "rotation_rad_per_rad",
                    "translation_m_per_rad")


def _correction(block: Any, source: str) -> RobotPoseCorrection | None:
    """The ``robot_pose_correction`` block, validated (None when absent)."""
    if block is None:
        return None
    where = "robot_pose_correction"
    if not isinstance(block, Mapping) or set(block) != set(_CORRECTION_KEYS):
        got = sorted(block) if isinstance(block, Mapping) else repr(block)
        raise _fail(source, f"'{where}' must be a mapping with exactly the keys "
                            f"{', '.join(_CORRECTION_KEYS)}, got {got}")
    if block["model"] != CORRECTION_MODEL:
        raise _fail(source, f"{where}.model: only '{CORRECTION_MODEL}' is known, got "
                            f"{block['model']!r} (written by a newer eye_in_hand?)")
    q = _vector(block, "reference_quat_xyzw", 4, f"{source}: {where}")
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > _QUAT_NORM_TOL:
        raise _fail(source, f"{where}.reference_quat_xyzw is not a unit quaternion (norm "
                            f"{norm:.9f})")
    mats = {}
    for key in ("rotation_rad_per_rad", "translation_m_per_rad"):
        try:
            arr = np.asarray(block[key], dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise _fail(source, f"{where}.{key} must be a 3x3 list of numbers") from exc
        if arr.shape != (3, 3):
            raise _fail(source, f"{where}.{key} must be 3x3 (3 rows of 3 numbers), got shape "
                                f"{arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise _fail(source, f"{where}.{key} contains NaN or infinite values")
        mats[key] = arr
    R_ref = from_xyz_quat(np.zeros(3), q / norm)[:3, :3]
    return RobotPoseCorrection(mats["rotation_rad_per_rad"], mats["translation_m_per_rad"],
                               R_ref)


def save_hand_eye(path: str | os.PathLike[str], calibration: HandEyeCalibration) -> Path:
    """Write ``hand_eye.yaml``.

    Args:
        path: output file; its folder is created.
        calibration: the calibration (validated again before writing).

    Returns:
        The path written.

    Raises:
        ConfigError: the calibration does not validate, or the file cannot be written.
    """
    out = Path(path)
    data = calibration.to_dict()
    hand_eye_from_dict(data, str(out))  # never write a file we could not read back
    from eye_in_hand.io.atomic import atomic_file

    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        with atomic_file(out, "w") as fh:  # temporary file, fsync, rename: never half written
            fh.write("# Hand-eye calibration: parent_T_child (metres, quaternion x y z w).\n")
            fh.write("# covariance order: x y z rx ry rz (rotation vector applied on the left).\n")
            yaml.safe_dump(data, fh, sort_keys=False, default_flow_style=None)
    except OSError as exc:
        raise ConfigError(f"{out}: cannot write hand-eye calibration ({exc})") from exc
    return out


def load_hand_eye(path: str | os.PathLike[str]) -> HandEyeCalibration:
    """Read and validate ``hand_eye.yaml``.

    Args:
        path: the file.

    Returns:
        The calibration.

    Raises:
        ConfigError: missing or unreadable file, YAML syntax error, or invalid content; the
            message names the file and the problem.
    """
    p = Path(path)
    return hand_eye_from_dict(read_yaml_file(p, "hand-eye calibration file"), str(p))
