"""Camera and stereo-rig models, and the camera_calibration_parsers YAML format.

:class:`CameraModel` holds what a ``sensor_msgs/CameraInfo`` holds: intrinsics ``K``,
distortion (``plumb_bob``: k1 k2 p1 p2 k3; ``rational_polynomial``: k1 k2 p1 p2 k3 k4 k5 k6),
image size, rectification rotation ``R`` and projection ``P``. It reads and writes the YAML
files of ROS's ``camera_calibration`` / ``camera_calibration_parsers``, so calibrations made by
ROS load here and ours load there.

:class:`StereoRig` holds two camera models and the extrinsic ``R, T`` in OpenCV's
``stereoCalibrate`` convention, ``X_right = R @ X_left + T`` (so ``right_T_left``), and the
rectification (``R1, R2, P1, P2, Q``). It is saved as ``left.yaml`` and ``right.yaml`` (each with
its rectification ``R`` and ``P``, the right ``P`` carrying ``-fx * B`` as stereo_image_proc
expects) plus ``stereo.yaml``; it loads from ROS's two files alone as well.

Units: whatever the calibration used for lengths (metres for our calibrations, "squares" for a
board of unit square), pixels for image coordinates.
"""
from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from eye_in_hand.core.transforms import as_finite_array
from eye_in_hand.errors import ConfigError, InputError
from eye_in_hand.yamlfile import read_yaml_file

__all__ = [
    "DISTORTION_MODELS",
    "CameraModel",
    "StereoRig",
    "matrix_to_yaml",
    "matrix_from_yaml",
]

#: Supported distortion models and their coefficient counts (ROS names).
DISTORTION_MODELS: dict[str, int] = {"plumb_bob": 5, "rational_polynomial": 8}

# Iterative undistortion: OpenCV's default of 5 iterations leaves errors of several pixels at
# the corners of strongly distorted images; iterate to convergence instead.
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
#: The zero rotation and translation ``cv2.projectPoints`` takes for camera-frame points (never
#: written to).
_NO_MOTION = np.zeros(3)


def _readonly(arr: np.ndarray) -> np.ndarray:
    arr = np.array(arr, dtype=np.float64, copy=True)
    arr.setflags(write=False)
    return arr


def _as_pixels(px: Any, name: str = "pixels") -> np.ndarray:
    arr = np.asarray(px, dtype=np.float64)
    if arr.ndim == 1 and arr.shape[0] == 2:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise InputError(f"{name}: expected shape (N, 2), got {np.shape(px)}")
    return arr


def matrix_to_yaml(M: np.ndarray) -> dict[str, Any]:
    """A matrix as camera_calibration_parsers writes it: ``{rows, cols, data}`` (row-major)."""
    arr = np.atleast_2d(np.asarray(M, dtype=np.float64))
    return {"rows": int(arr.shape[0]), "cols": int(arr.shape[1]),
            "data": [float(v) for v in arr.ravel()]}


def matrix_from_yaml(node: Any, key: str, source: str,
                     shape: tuple[int, int] | None = None) -> np.ndarray:
    """Read a ``{rows, cols, data}`` matrix, raising :class:`ConfigError` naming file and key."""
    if not isinstance(node, Mapping) or not {"rows", "cols", "data"} <= set(node):
        raise ConfigError(f"{source}: '{key}' must be a mapping with rows, cols and data")
    try:
        rows, cols = int(node["rows"]), int(node["cols"])
        data = np.asarray(node["data"], dtype=np.float64).ravel()
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{source}: '{key}' has non-numeric rows, cols or data") from exc
    if data.size != rows * cols:
        raise ConfigError(
            f"{source}: '{key}' declares {rows}x{cols} but has {data.size} values")
    if shape is not None and (rows, cols) != shape:
        raise ConfigError(f"{source}: '{key}' must be {shape[0]}x{shape[1]}, got {rows}x{cols}")
    if not np.all(np.isfinite(data)):
        raise ConfigError(f"{source}: '{key}' contains NaN or infinite values")
    return data.reshape(rows, cols)


@dataclass(frozen=True, eq=False)
class CameraModel:
    """A calibrated camera, as in ``sensor_msgs/CameraInfo``.

    Attributes:
        K: intrinsic matrix, shape (3, 3).
        dist: distortion coefficients, shape (5,) for plumb_bob, (8,) for rational_polynomial.
        width, height: image size in pixels.
        distortion_model: ``"plumb_bob"`` or ``"rational_polynomial"``.
        R: rectification rotation, shape (3, 3) (identity for a mono camera).
        P: projection matrix of the rectified image, shape (3, 4) (default ``[K | 0]``).
        name: the camera name written to YAML.
    """

    K: np.ndarray
    dist: np.ndarray
    width: int
    height: int
    distortion_model: str = "plumb_bob"
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    # None: [K | 0]; __post_init__ always stores an array, which is what readers see
    P: np.ndarray = None  # type: ignore[assignment]
    name: str = "camera"

    def __post_init__(self) -> None:
        K = as_finite_array(self.K, "K", (3, 3))
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise InputError(f"K: focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}")
        if np.max(np.abs(K[2] - (0.0, 0.0, 1.0))) > 1e-9 or K[1, 0] != 0 or K[2, 0] != 0:
            raise InputError("K: expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got "
                             f"{K.tolist()}")
        if self.distortion_model not in DISTORTION_MODELS:
            raise InputError(f"distortion_model: '{self.distortion_model}' is not supported "
                             f"(supported: {', '.join(DISTORTION_MODELS)})")
        n = DISTORTION_MODELS[self.distortion_model]
        dist = np.asarray(self.dist, dtype=np.float64).ravel()
        if dist.size < n and np.all(np.isfinite(dist)):
            dist = np.concatenate([dist, np.zeros(n - dist.size)])  # e.g. 4-coefficient plumb_bob
        dist = as_finite_array(dist, "dist", (n,))
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise InputError(f"image size must be positive, got {self.width}x{self.height}")
        R = as_finite_array(self.R, "R", (3, 3))
        if np.max(np.abs(R.T @ R - np.eye(3))) > 1e-5 or np.linalg.det(R) < 0:
            raise InputError("R: rectification matrix is not a rotation")
        P = (np.hstack([K, np.zeros((3, 1))]) if self.P is None
             else as_finite_array(self.P, "P", (3, 4)))
        object.__setattr__(self, "K", _readonly(K))
        object.__setattr__(self, "dist", _readonly(dist))
        object.__setattr__(self, "R", _readonly(R))
        object.__setattr__(self, "P", _readonly(P))
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    # -- properties -----------------------------------------------------------------------
    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def size(self) -> tuple[int, int]:
        """Image size as OpenCV takes it: (width, height)."""
        return (self.width, self.height)

    # -- geometry -------------------------------------------------------------------------
    def project(self, points_cam: Any) -> np.ndarray:
        """Project camera-frame points to distorted pixel coordinates.

        Args:
            points_cam: array-like, shape (N, 3) or (3,), in this camera's optical frame.

        Returns:
            shape (N, 2); rows for points with z <= 0 are NaN.
        """
        pts = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
        out = np.full((pts.shape[0], 2), np.nan)
        ok = pts[:, 2] > 0
        if np.any(ok):
            img, _ = cv2.projectPoints(pts[ok].reshape(-1, 1, 3), _NO_MOTION, _NO_MOTION,
                                       self.K, self.dist)
            out[ok] = img.reshape(-1, 2)
        return out

    def project_direction(self, x: float, y: float) -> np.ndarray:
        """The distorted pixel, shape (2,), of one ideal normalised point ``(x, y)`` (the
        direction ``(x, y, 1)``): :meth:`project` of that direction, to the last bit, without
        its checks and masks (a third of its time; the detector and the stereo locator call
        it for every blob)."""
        img, _ = cv2.projectPoints(np.array([[[x, y, 1.0]]]), _NO_MOTION, _NO_MOTION, self.K,
                                   self.dist)
        return img.reshape(2)

    def project_directions(self, xy: np.ndarray) -> np.ndarray:
        """:meth:`project_direction` of each ideal normalised point, ``xy`` shape (N, 2), in one
        ``cv2.projectPoints`` call: the pixels, shape (N, 2), to the last bit (OpenCV projects
        each point on its own)."""
        pts = np.ones((len(xy), 1, 3))
        pts[:, 0, :2] = xy
        img, _ = cv2.projectPoints(pts, _NO_MOTION, _NO_MOTION, self.K, self.dist)
        return img.reshape(-1, 2)

    def undistort_points(self, px: Any) -> np.ndarray:
        """Distorted pixels to ideal normalised coordinates (x/z, y/z), shape (N, 2)."""
        pts = _as_pixels(px).reshape(-1, 1, 2)
        if pts.shape[0] == 0:
            return np.zeros((0, 2))
        out = cv2.undistortPoints(pts, self.K, self.dist, None, None, None, _UNDISTORT_CRITERIA)
        return out.reshape(-1, 2)

    def rectify_points(self, px: Any) -> np.ndarray:
        """Distorted pixels to rectified pixel coordinates (through ``R`` and ``P``), (N, 2)."""
        pts = _as_pixels(px).reshape(-1, 1, 2)
        if pts.shape[0] == 0:
            return np.zeros((0, 2))
        out = cv2.undistortPoints(pts, self.K, self.dist, None, self.R, self.P[:3, :3],
                                      _UNDISTORT_CRITERIA)
        return out.reshape(-1, 2)

    def with_rectification(self, R: Any, P: Any) -> CameraModel:
        """A copy with the given rectification rotation (3, 3) and projection (3, 4)."""
        return replace(self, R=np.asarray(R, dtype=np.float64), P=np.asarray(P, dtype=np.float64))

    # -- YAML (camera_calibration_parsers) -----------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The camera_calibration_parsers YAML content as a dict."""
        return {
            "image_width": self.width,
            "image_height": self.height,
            "camera_name": self.name,
            "camera_matrix": matrix_to_yaml(self.K),
            "distortion_model": self.distortion_model,
            "distortion_coefficients": matrix_to_yaml(self.dist[None, :]),
            "rectification_matrix": matrix_to_yaml(self.R),
            "projection_matrix": matrix_to_yaml(self.P),
        }

    @classmethod
    def from_dict(cls, data: Any, source: str = "<camera>") -> CameraModel:
        """Build from camera_calibration_parsers YAML content.

        Raises:
            ConfigError: a key is missing or has the wrong shape; names ``source`` and the key.
        """
        if not isinstance(data, Mapping):
            raise ConfigError(f"{source}: expected a YAML mapping, got {type(data).__name__}")
        required = ("image_width", "image_height", "camera_matrix", "distortion_coefficients")
        missing = [k for k in required if k not in data]
        if missing:
            raise ConfigError(f"{source}: missing key(s) {', '.join(missing)}")
        K = matrix_from_yaml(data["camera_matrix"], "camera_matrix", source, (3, 3))
        dist = matrix_from_yaml(data["distortion_coefficients"], "distortion_coefficients",
                                source).ravel()
        model = str(data.get("distortion_model", "plumb_bob"))
        if model not in DISTORTION_MODELS:
            raise ConfigError(f"{source}: distortion_model '{model}' is not supported "
                              f"(supported: {', '.join(DISTORTION_MODELS)})")
        n = DISTORTION_MODELS[model]
        if dist.size > n or (dist.size < n and not (model == "plumb_bob" and dist.size == 4)):
            raise ConfigError(f"{source}: distortion_coefficients has {dist.size} values, "
                              f"'{model}' takes {n}")
        R = (matrix_from_yaml(data["rectification_matrix"], "rectification_matrix", source, (3, 3))
             if "rectification_matrix" in data else np.eye(3))
        P: Any = (matrix_from_yaml(data["projection_matrix"], "projection_matrix", source,
                                   (3, 4))
             if "projection_matrix" in data else None)
        try:
            return cls(K=K, dist=dist, width=int(data["image_width"]),
                       height=int(data["image_height"]), distortion_model=model, R=R, P=P,
                       name=str(data.get("camera_name", "camera")))
        except (InputError, TypeError, ValueError) as exc:
            raise ConfigError(f"{source}: {exc}") from exc

    def save_yaml(self, path: str | os.PathLike[str]) -> Path:
        """Write the camera_calibration_parsers YAML file; returns the path."""
        path = Path(path)
        path.write_text(yaml.safe_dump(self.to_dict(), sort_keys=False, default_flow_style=None))
        return path

    @classmethod
    def load_yaml(cls, path: str | os.PathLike[str]) -> CameraModel:
        """Read a camera_calibration_parsers YAML file.

        Raises:
            ConfigError: the file is missing, unreadable, not YAML, or malformed (names the file).
        """
        return cls.from_dict(read_yaml_file(path, "calibration file"), source=str(Path(path)))


@dataclass(frozen=True, eq=False)
class StereoRig:
    """Two cameras and the rigid transform between them.

    Attributes:
        left, right: the camera models; after :meth:`rectified` their ``R`` and ``P`` are the
            rectification (``R1, P1`` and ``R2, P2``).
        R: rotation, shape (3, 3), and
        T: translation, shape (3,), with ``X_right = R @ X_left + T`` (OpenCV's stereoCalibrate).
        Q: disparity-to-depth matrix, shape (4, 4), once rectified (else None).
    """

    left: CameraModel
    right: CameraModel
    R: np.ndarray
    T: np.ndarray
    Q: np.ndarray | None = None

    def __post_init__(self) -> None:
        R = as_finite_array(self.R, "R", (3, 3))
        if np.max(np.abs(R.T @ R - np.eye(3))) > 1e-5 or np.linalg.det(R) < 0:
            raise InputError("R: stereo rotation is not a rotation matrix")
        T = as_finite_array(np.ravel(self.T), "T", (3,))
        if np.linalg.norm(T) <= 0:
            raise InputError("T: stereo baseline is zero")
        object.__setattr__(self, "R", _readonly(R))
        object.__setattr__(self, "T", _readonly(T))
        if self.Q is not None:
            object.__setattr__(self, "Q", _readonly(as_finite_array(self.Q, "Q", (4, 4))))

    @property
    def baseline(self) -> float:
        """Distance between the optical centres, ``|T|``."""
        return float(np.linalg.norm(self.T))

    @property
    def right_T_left(self) -> np.ndarray:
        """4x4 transform mapping left-camera points into the right camera frame."""
        out = np.eye(4)
        out[:3, :3] = self.R
        out[:3, 3] = self.T
        return out

    @property
    def is_rectified(self) -> bool:
        return self.Q is not None

    @property
    def R1(self) -> np.ndarray:
        return self.left.R

    @property
    def R2(self) -> np.ndarray:
        return self.right.R

    @property
    def P1(self) -> np.ndarray:
        return self.left.P

    @property
    def P2(self) -> np.ndarray:
        return self.right.P

    def rectified(self, alpha: float = 0.0, *, zero_disparity: bool = True) -> StereoRig:
        """Compute the rectification with ``cv2.stereoRectify``.

        Args:
            alpha: free scaling, 0 (only valid pixels) to 1 (all source pixels kept), or -1 for
                OpenCV's default.
            zero_disparity: make the principal points equal (``CALIB_ZERO_DISPARITY``).

        Returns:
            A rig whose cameras carry ``R1, P1`` / ``R2, P2`` and whose ``Q`` is set.
        """
        if self.left.size != self.right.size:
            raise InputError(f"left and right image sizes differ: {self.left.size} vs "
                             f"{self.right.size}")
        if not (alpha == -1 or 0.0 <= alpha <= 1.0):
            raise InputError(f"alpha: expected -1 or a value in [0, 1], got {alpha}")
        flags = cv2.CALIB_ZERO_DISPARITY if zero_disparity else 0
        R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
            self.left.K, self.left.dist, self.right.K, self.right.dist, self.left.size,
            self.R, self.T.reshape(3, 1), flags=flags, alpha=alpha)
        return StereoRig(left=self.left.with_rectification(R1, P1),
                         right=self.right.with_rectification(R2, P2), R=self.R, T=self.T, Q=Q)

    @classmethod
    def from_ros_pair(cls, left: CameraModel, right: CameraModel,
                      source: str = "<left/right>") -> StereoRig:
        """Rebuild the extrinsic from ROS's rectification ``R`` and projection ``P`` of each side.

        In ROS's stereo CameraInfo, the rectified frames differ by a pure translation carried in
        the right projection, ``P2[0, 3] = -fx' * B`` (and ``P2[1, 3]`` for a vertical rig). With
        ``R_rect_l = R1 @ X_l`` and ``R_rect_r = R2 @ X_r``: ``R = R2^T R1``, ``T = R2^T t_rect``.

        Raises:
            ConfigError: the right projection carries no baseline (not a stereo calibration), or
                the left projection has a translation.
        """
        P1, P2 = left.P, right.P
        if np.any(np.abs(P1[:, 3]) > 1e-9):
            raise ConfigError(f"{source}: left projection_matrix must have a zero last column, "
                              f"got {P1[:, 3].tolist()}")
        t_rect = np.array([P2[0, 3] / P2[0, 0], P2[1, 3] / P2[1, 1], P2[2, 3]])
        if np.linalg.norm(t_rect) <= 1e-12:
            raise ConfigError(
                f"{source}: right projection_matrix has no baseline (P[0,3] = P[1,3] = 0): "
                "these files are not a stereo calibration")
        R = right.R.T @ left.R
        T = right.R.T @ t_rect
        f = P1[0, 0]
        if abs(t_rect[0]) >= abs(t_rect[1]):
            tx = t_rect[0]
            Q = np.array([[1.0, 0.0, 0.0, -P1[0, 2]],
                          [0.0, 1.0, 0.0, -P1[1, 2]],
                          [0.0, 0.0, 0.0, f],
                          [0.0, 0.0, -1.0 / tx, (P1[0, 2] - P2[0, 2]) / tx]])
        else:
            ty = t_rect[1]
            Q = np.array([[1.0, 0.0, 0.0, -P1[0, 2]],
                          [0.0, 1.0, 0.0, -P1[1, 2]],
                          [0.0, 0.0, 0.0, f],
                          [0.0, 0.0, -1.0 / ty, (P1[1, 2] - P2[1, 2]) / ty]])
        return cls(left=left, right=right, R=R, T=T, Q=Q)

    # -- files ----------------------------------------------------------------------------
    def stereo_dict(self) -> dict[str, Any]:
        """Content of ``stereo.yaml``."""
        out: dict[str, Any] = {
            "image_width": self.left.width,
            "image_height": self.left.height,
            "convention": "X_right = R * X_left + T (OpenCV stereoCalibrate)",
            "baseline": self.baseline,
            "R": matrix_to_yaml(self.R),
            "T": matrix_to_yaml(self.T.reshape(3, 1)),
        }
        if self.Q is not None:
            out.update({"R1": matrix_to_yaml(self.R1), "R2": matrix_to_yaml(self.R2),
                        "P1": matrix_to_yaml(self.P1), "P2": matrix_to_yaml(self.P2),
                        "Q": matrix_to_yaml(self.Q)})
        return out

    def save(self, directory: str | os.PathLike[str]) -> tuple[Path, Path, Path]:
        """Write ``left.yaml``, ``right.yaml`` and ``stereo.yaml`` into ``directory``.

        The rig is rectified first (alpha 0) if it is not yet, because ROS's two files carry
        the stereo geometry only in their rectification R and projection P.
        """
        rig = self if self.is_rectified else self.rectified()
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        left_name = rig.left.name if rig.left.name != "camera" else "left"
        right_name = rig.right.name if rig.right.name != "camera" else "right"
        lp = replace(rig.left, name=left_name).save_yaml(directory / "left.yaml")
        rp = replace(rig.right, name=right_name).save_yaml(directory / "right.yaml")
        sp = directory / "stereo.yaml"
        sp.write_text(yaml.safe_dump(rig.stereo_dict(), sort_keys=False, default_flow_style=None))
        return lp, rp, sp

    @classmethod
    def load(cls, directory: str | os.PathLike[str]) -> StereoRig:
        """Read a rig from ``directory``.

        ``left.yaml`` and ``right.yaml`` are required (as ROS's camera_calibration writes them);
        ``stereo.yaml``, when present, supplies the extrinsic ``R, T`` directly.

        Raises:
            ConfigError: a file is missing or malformed, or the two files do not describe a stereo
                pair (naming the file).
        """
        directory = Path(directory)
        if not directory.is_dir():
            raise ConfigError(f"{directory}: calibration directory not found")
        left = CameraModel.load_yaml(directory / "left.yaml")
        right = CameraModel.load_yaml(directory / "right.yaml")
        stereo_path = directory / "stereo.yaml"
        if not stereo_path.exists():
            return cls.from_ros_pair(left, right, source=f"{directory}/right.yaml")
        return cls.from_stereo_file(left, right, stereo_path)

    @classmethod
    def from_stereo_file(cls, left: CameraModel, right: CameraModel,
                         stereo_path: str | os.PathLike[str]) -> StereoRig:
        """A rig from two camera models and the ``R``, ``T`` (and ``Q``) of a ``stereo.yaml``.

        Raises:
            ConfigError: the file is missing, not YAML, or lacks a valid R or T (names it).
        """
        stereo_path = Path(stereo_path)
        data = read_yaml_file(stereo_path, "stereo calibration")
        if not isinstance(data, Mapping) or "R" not in data or "T" not in data:
            raise ConfigError(f"{stereo_path}: expected a mapping with R and T")
        R = matrix_from_yaml(data["R"], "R", str(stereo_path), (3, 3))
        T = matrix_from_yaml(data["T"], "T", str(stereo_path)).ravel()
        if T.size != 3:
            raise ConfigError(f"{stereo_path}: 'T' must have 3 values, got {T.size}")
        Q = (matrix_from_yaml(data["Q"], "Q", str(stereo_path), (4, 4)) if "Q" in data else None)
        try:
            return cls(left=left, right=right, R=R, T=T, Q=Q)
        except InputError as exc:
            raise ConfigError(f"{stereo_path}: {exc}") from exc
