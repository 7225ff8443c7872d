"""The synthetic eye-in-hand world: arm, stereo rig on the tool, targets, chessboard, table.

Everything geometric is a field of :class:`World` and round-trips through ``world.yaml``
(:meth:`World.from_yaml` / :meth:`World.to_yaml`); ``config/world.yaml`` holds the default,
which :meth:`World.default` reproduces exactly.

Frames follow ur_description: ``base_link`` is the world frame (targets, board and table are
given in it; the table top is the plane ``z = table.height``); the arm's DH chain is expressed
in ``base`` (UR's controller frame, DH frame 0), with ``base_link`` -> ``base`` = Rz(pi)
(``arm.base_T_dh``, published on ``/tf_static``). ``tool0`` is the last DH frame; ``arm.fk``
gives ``base_link`` -> ``tool0``. All names are the ``arm`` section's (``base_frame``,
``dh_frame``, ``link_names``). ``camera_left_optical_frame``
is ``base_T_ee @ ee_T_cam`` (x right, y down, z forward); the right camera follows OpenCV's
``X_right = R @ X_left + T`` (``world.rig.R``, ``world.rig.T``).

Board frame (``base_T_board``): origin at OpenCV's first inner corner, x along the ``cols``
(9-corner) direction, y along the ``rows`` direction, z = x cross y; the board's printed face
looks along -z, so cameras see it from the -z side, as OpenCV's PnP assumes.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, cast

import numpy as np
import yaml

from eye_in_hand.core.calibration import BoardSpec
from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.core.kinematics import DHChain
from eye_in_hand.core.transforms import (
    as_transform,
    compose,
    from_rotvec,
    from_xyz_quat,
    invert,
    to_xyz_quat,
)
from eye_in_hand.errors import ConfigError, EyeInHandError, InputError
from eye_in_hand.sim.render import Renderer
from eye_in_hand.sim.robot_error import RobotErrorSpec, draw_true_arm
from eye_in_hand.yamlfile import read_yaml_file

__all__ = ["Target", "World", "DEFAULT_WORLD_YAML", "pose_to_dict", "pose_from_dict"]

#: The shipped default world file (the same numbers as :meth:`World.default`).
DEFAULT_WORLD_YAML = Path(__file__).resolve().parents[2] / "config" / "world.yaml"


def pose_to_dict(T: np.ndarray) -> dict[str, list[float]]:
    """``{translation: [x, y, z], quat_xyzw: [x, y, z, w]}`` of a (4, 4) transform."""
    xyz, q = to_xyz_quat(T)
    return {"translation": [float(v) for v in xyz], "quat_xyzw": [float(v) for v in q]}


def pose_from_dict(data: Any, where: str) -> np.ndarray:
    """Inverse of :func:`pose_to_dict`; also accepts ``rotvec`` instead of ``quat_xyzw``.

    Raises:
        ConfigError: missing keys or malformed numbers (the message names ``where``).
    """
    if not isinstance(data, Mapping) or "translation" not in data:
        raise ConfigError(f"{where}: expected a mapping with translation and quat_xyzw")
    try:
        if "quat_xyzw" in data:
            return from_xyz_quat(data["translation"], data["quat_xyzw"])
        if "rotvec" in data:
            return from_rotvec(data["rotvec"], data["translation"])
    except (EyeInHandError, ValueError, TypeError) as exc:
        raise ConfigError(f"{where}: {exc}") from exc
    raise ConfigError(f"{where}: needs quat_xyzw (or rotvec) next to translation")


@dataclass(frozen=True)
class Target:
    """A coloured sphere.

    Attributes:
        name: identifier (the order of targets in ground truth follows ``world.targets``).
        center_base: centre in ``base_link``, shape (3,), metres.
        radius_m: sphere radius, metres.
        color_bgr: albedo as 0-255 BGR.
    """

    name: str
    center_base: np.ndarray
    radius_m: float
    color_bgr: tuple[int, int, int] = (40, 40, 210)

    def __post_init__(self) -> None:
        c = np.asarray(self.center_base, dtype=np.float64).reshape(-1)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise InputError(f"target {self.name!r}: center_base must be 3 finite numbers")
        if not (math.isfinite(self.radius_m) and self.radius_m > 0):
            raise InputError(f"target {self.name!r}: radius_m must be positive")
        col = tuple(int(v) for v in self.color_bgr)
        if len(col) != 3 or any(v < 0 or v > 255 for v in col):
            raise InputError(f"target {self.name!r}: color_bgr must be 3 values in 0..255")
        c.setflags(write=False)
        object.__setattr__(self, "center_base", c)
        object.__setattr__(self, "radius_m", float(self.radius_m))
        object.__setattr__(self, "color_bgr", col)


def _camera_from_dict(data: Any, where: str) -> CameraModel:
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: expected a mapping")
    try:
        K = np.array([[float(data["fx"]), 0.0, float(data["cx"])],
                      [0.0, float(data["fy"]), float(data["cy"])],
                      [0.0, 0.0, 1.0]])
        return CameraModel(K=K, dist=np.asarray(data.get("dist", [0.0] * 5), dtype=float),
                           width=int(data["width"]), height=int(data["height"]),
                           distortion_model=str(data.get("distortion_model", "plumb_bob")),
                           name=str(data.get("name", where)))
    except KeyError as exc:
        raise ConfigError(f"{where}: missing key {exc.args[0]!r} "
                          "(need width, height, fx, fy, cx, cy, dist)") from exc
    except (EyeInHandError, ValueError, TypeError) as exc:
        raise ConfigError(f"{where}: {exc}") from exc


def _camera_to_dict(cam: CameraModel) -> dict[str, Any]:
    return {"name": cam.name, "width": cam.width, "height": cam.height,
            "fx": float(cam.fx), "fy": float(cam.fy), "cx": float(cam.cx), "cy": float(cam.cy),
            "distortion_model": cam.distortion_model, "dist": [float(v) for v in cam.dist]}


@dataclass(frozen=True, eq=False)
class World:
    """Ground truth of the synthetic scene (see the module docstring for frames).

    Attributes:
        rig: the stereo rig with distortion, not rectified (ground truth).
        ee_T_cam: (4, 4) ``tool0`` -> ``camera_left_optical_frame`` (the true hand-eye).
        arm: the arm's nominal kinematic chain (``fk(q) -> base_T_ee``, ``ik``): what the
            robot reports (``/joint_states``, ``/ee_pose``, ``/tf``).
        targets: the coloured spheres.
        board: the chessboard (:class:`~eye_in_hand.core.calibration.BoardSpec`).
        base_T_board: (4, 4) board pose in ``base_link``.
        board_margin: white border around the outer squares, metres.
        table_height: z of the table plane in ``base_link``, metres.
        table_color_bgr: mean table albedo (0-255 BGR); the texture varies around it.
        texture_seed: seed of the procedural table texture (part of the scene, not the noise).
        light_dir_base: unit vector towards the light in ``base_link``, shape (3,).
        ambient: ambient fraction of the shading in [0, 1].
        robot_error: how the true arm (which the images come from) differs from ``arm``
            (:class:`~eye_in_hand.sim.robot_error.RobotErrorSpec`; default the realistic
            default, ``RobotErrorSpec.none()`` for the ideal arm).
    """

    rig: StereoRig
    ee_T_cam: np.ndarray
    arm: DHChain
    targets: tuple[Target, ...]
    board: BoardSpec
    base_T_board: np.ndarray
    board_margin: float = 0.02
    table_height: float = 0.0
    table_color_bgr: tuple[int, int, int] = (120, 135, 150)
    texture_seed: int = 7
    light_dir_base: np.ndarray = field(default_factory=lambda: np.array([0.3, -0.2, 1.0]))
    ambient: float = 0.35
    robot_error: RobotErrorSpec = field(default_factory=RobotErrorSpec.default)

    def __post_init__(self) -> None:
        if not isinstance(self.robot_error, RobotErrorSpec):
            raise InputError("robot_error: expected a RobotErrorSpec")
        ee_T_cam = as_transform(self.ee_T_cam, "ee_T_cam")
        base_T_board = as_transform(self.base_T_board, "base_T_board")
        light = np.asarray(self.light_dir_base, dtype=np.float64).reshape(-1)
        if light.shape != (3,) or not np.linalg.norm(light) > 0:
            raise InputError("light_dir_base: expected a non-zero 3-vector")
        if not 0.0 <= self.ambient <= 1.0:
            raise InputError(f"ambient must be in [0, 1], got {self.ambient}")
        if self.board.kind != "chessboard":
            raise InputError(f"the simulator renders chessboards only, got {self.board.kind}")
        if self.rig.left.size != self.rig.right.size:
            raise InputError("left and right cameras must have the same image size")
        for name, arr in (("ee_T_cam", ee_T_cam), ("base_T_board", base_T_board),
                          ("light_dir_base", light / np.linalg.norm(light))):
            arr = np.array(arr, dtype=np.float64)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "targets", tuple(self.targets))

    # -- construction ---------------------------------------------------------------------
    @classmethod
    def default(cls) -> World:
        """The default world: UR5e, 1280x720 stereo pair (fx ~ 900 px, 60 mm baseline, radial
        and tangential distortion, a small inter-camera rotation), one red sphere, a 9x6
        chessboard with 25 mm squares lying on a textured table."""
        left = CameraModel(
            K=np.array([[902.5, 0.0, 638.2], [0.0, 901.8, 361.4], [0.0, 0.0, 1.0]]),
            dist=np.array([-0.118, 0.082, 0.00061, -0.00042, -0.021]),
            width=1280, height=720, name="camera_left")
        right = CameraModel(
            K=np.array([[898.7, 0.0, 643.9], [0.0, 898.1, 357.6], [0.0, 0.0, 1.0]]),
            dist=np.array([-0.112, 0.075, -0.00037, 0.00055, -0.017]),
            width=1280, height=720, name="camera_right")
        right_T_left = from_rotvec([0.0035, -0.0112, 0.0021], [-0.0600, 0.00042, 0.00061])
        rig = StereoRig(left=left, right=right, R=right_T_left[:3, :3], T=right_T_left[:3, 3])
        # Camera on the tool: optical axis close to tool z, image x rotated ~90 deg about it.
        ee_T_cam = from_rotvec([0.021, -0.034, 1.5708 + 0.012], [0.032, -0.061, 0.041])
        board = BoardSpec("chessboard", 9, 6, 0.025)
        # Board lying face up on the table: x along base x (rotated 12 deg about z), z down.
        yaw = math.radians(12.0)
        Rz = np.array([[math.cos(yaw), -math.sin(yaw), 0.0],
                       [math.sin(yaw), math.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
        R_board = Rz @ np.diag([1.0, -1.0, -1.0])
        center = np.array([0.42, -0.18, 0.003])
        half = np.array([(board.cols - 1) * board.square / 2, (board.rows - 1) * board.square / 2,
                         0.0])
        base_T_board = np.eye(4)
        base_T_board[:3, :3] = R_board
        base_T_board[:3, 3] = center - R_board @ half
        target = Target("target_0", np.array([0.48, 0.16, 0.035]), 0.035, (40, 40, 210))
        return cls(rig=rig, ee_T_cam=ee_T_cam, arm=DHChain.ur5e(), targets=(target,),
                   board=board, base_T_board=base_T_board)

    @classmethod
    def from_dict(cls, data: Any, source: str = "<world>") -> World:
        """Build a world from the ``world.yaml`` mapping (see ``config/world.yaml``).

        Raises:
            ConfigError: a section is missing or malformed (the message names it).
        """
        if not isinstance(data, Mapping):
            raise ConfigError(f"{source}: expected a mapping at the top level")

        def section(key: str) -> Any:
            if key not in data:
                raise ConfigError(f"{source}: missing section {key!r}")
            return data[key]

        rig_d = section("rig")
        left = _camera_from_dict(rig_d.get("left"), f"{source}: rig.left")
        right = _camera_from_dict(rig_d.get("right"), f"{source}: rig.right")
        right_T_left = pose_from_dict(rig_d.get("right_T_left"), f"{source}: rig.right_T_left")
        try:
            rig = StereoRig(left=left, right=right, R=right_T_left[:3, :3],
                            T=right_T_left[:3, 3])
            arm_d = section("arm")
            if arm_d.get("type", "dh") != "dh":
                raise ConfigError(f"{source}: arm.type must be 'dh'")
            arm = DHChain.from_dict(arm_d)
            targets = tuple(
                Target(str(t.get("name", f"target_{i}")), np.asarray(t["center_base"], float),
                       float(t["radius_m"]), tuple(t.get("color_bgr", (40, 40, 210))))
                for i, t in enumerate(section("targets")))
            board_d = section("board")
            board = BoardSpec.parse(str(board_d["spec"]))
            table = data.get("table", {}) or {}
            light = data.get("light", {}) or {}
            return cls(
                rig=rig,
                ee_T_cam=pose_from_dict(section("ee_T_cam"), f"{source}: ee_T_cam"),
                arm=arm, targets=targets, board=board,
                base_T_board=pose_from_dict(board_d.get("base_T_board"),
                                            f"{source}: board.base_T_board"),
                board_margin=float(board_d.get("margin", 0.02)),
                table_height=float(table.get("height", 0.0)),
                table_color_bgr=cast(tuple[int, int, int], tuple(
                    int(v) for v in table.get("color_bgr", (120, 135, 150)))),
                texture_seed=int(table.get("texture_seed", 7)),
                light_dir_base=np.asarray(light.get("direction_base", (0.3, -0.2, 1.0)), float),
                ambient=float(light.get("ambient", 0.35)),
                robot_error=RobotErrorSpec.from_dict(data["robot_error"],
                                                     f"{source}: robot_error")
                if "robot_error" in data else RobotErrorSpec.default(),
            )
        except ConfigError:
            raise
        except KeyError as exc:
            raise ConfigError(f"{source}: missing key {exc.args[0]!r}") from exc
        except (EyeInHandError, ValueError, TypeError, AttributeError) as exc:
            raise ConfigError(f"{source}: {exc}") from exc

    def to_dict(self) -> dict[str, Any]:
        """The ``world.yaml`` mapping (plain Python types)."""
        return {
            "rig": {"left": _camera_to_dict(self.rig.left),
                    "right": _camera_to_dict(self.rig.right),
                    "right_T_left": pose_to_dict(self.rig.right_T_left)},
            "ee_T_cam": pose_to_dict(self.ee_T_cam),
            "arm": {"type": "dh", **self.arm.to_dict()},
            "targets": [{"name": t.name, "center_base": [float(v) for v in t.center_base],
                         "radius_m": t.radius_m, "color_bgr": list(t.color_bgr)}
                        for t in self.targets],
            "board": {"spec": str(self.board), "margin": self.board_margin,
                      "base_T_board": pose_to_dict(self.base_T_board)},
            "table": {"height": self.table_height, "color_bgr": list(self.table_color_bgr),
                      "texture_seed": self.texture_seed},
            "light": {"direction_base": [float(v) for v in self.light_dir_base],
                      "ambient": self.ambient},
            "robot_error": self.robot_error.to_dict(),
        }

    @classmethod
    def from_yaml(cls, path: str | Path) -> World:
        """Load a world file.

        Raises:
            ConfigError: the file cannot be read or is malformed.
        """
        p = Path(path)
        return cls.from_dict(read_yaml_file(p, "world file"), source=str(p))

    def to_yaml(self, path: str | Path) -> Path:
        """Write the world file; returns its path."""
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        header = ("# eye_in_hand synthetic world. Metres, radians, pixels; poses as "
                  "translation +\n"
                  "# quat_xyzw (a_T_b maps points in b into a). rig.right_T_left follows OpenCV:\n"
                  "# X_right = R X_left + T. Board frame: origin at the first inner corner.\n")
        p.write_text(header + yaml.safe_dump(self.to_dict(), sort_keys=False), encoding="utf-8")
        return p

    def with_image_size(self, width: int, height: int) -> World:
        """The same world with both cameras resampled to ``width`` x ``height`` pixels.

        Focal lengths and principal points scale with the size ratio per axis (the field of
        view is kept); distortion coefficients are unchanged (they act on normalised
        coordinates).
        """
        if width <= 0 or height <= 0:
            raise InputError(f"image size must be positive, got {width}x{height}")
        cams = []
        for cam in (self.rig.left, self.rig.right):
            sx, sy = width / cam.width, height / cam.height
            K = cam.K.copy()
            K[0, 0] *= sx
            K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
            K[1, 1] *= sy
            K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
            cams.append(CameraModel(K=K, dist=cam.dist, width=width, height=height,
                                    distortion_model=cam.distortion_model, name=cam.name))
        rig = StereoRig(left=cams[0], right=cams[1], R=self.rig.R, T=self.rig.T)
        return replace(self, rig=rig)

    def with_robot_error(self, spec: RobotErrorSpec) -> World:
        """The same world with another robot error (``RobotErrorSpec.none()``: ideal arm)."""
        return replace(self, robot_error=spec)

    @property
    def true_arm(self) -> DHChain:
        """The true arm (``arm`` perturbed by ``robot_error``, drawn once from its seed);
        the images come from it. ``arm`` itself when the kinematic error is zero."""
        cached = self.__dict__.get("_true_arm_cache")
        if cached is None:
            cached = draw_true_arm(self.arm, self.robot_error)
            object.__setattr__(self, "_true_arm_cache", cached)
        return cached

    # -- geometry helpers -----------------------------------------------------------------
    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) of both cameras."""
        return self.rig.left.width, self.rig.left.height

    @property
    def left_T_right(self) -> np.ndarray:
        """(4, 4) right optical frame -> left optical frame."""
        return invert(self.rig.right_T_left)

    def board_points(self) -> np.ndarray:
        """Inner corners in the board frame, OpenCV order (row by row), shape (N, 3)."""
        s = self.board.square
        j, i = np.mgrid[0:self.board.rows, 0:self.board.cols]
        return np.stack([i.ravel() * s, j.ravel() * s, np.zeros(i.size)], axis=1)

    def board_points_base(self) -> np.ndarray:
        """Inner corners in ``base_link``, shape (N, 3)."""
        P = self.board_points()
        return P @ self.base_T_board[:3, :3].T + self.base_T_board[:3, 3]

    def board_center_base(self) -> np.ndarray:
        """Centre of the inner-corner grid in ``base_link``, shape (3,)."""
        return self.board_points_base().mean(axis=0)

    def base_T_cam(self, q: Sequence[float] | np.ndarray) -> np.ndarray:
        """(4, 4) true left optical frame in ``base_link`` at true joint vector ``q``."""
        return compose(self.true_arm.fk(q), self.ee_T_cam)

    def target_centers_base(self) -> np.ndarray:
        """Target centres in ``base_link``, shape (M, 3)."""
        return np.array([t.center_base for t in self.targets]).reshape(-1, 3)

    def render(self, q, **kwargs):
        """Render the stereo pair at joint vector ``q``; see :meth:`Renderer.render`."""
        return self._renderer().render(q, **kwargs)

    def truth(self, q):
        """Ground truth at joint vector ``q`` without rendering (:class:`FrameTruth`)."""
        return self._renderer().truth(q)

    def _renderer(self) -> Renderer:
        cached = self.__dict__.get("_renderer_cache")
        if cached is None:
            cached = Renderer(self)
            object.__setattr__(self, "_renderer_cache", cached)
        return cached
