"""Synthetic hand-eye problems with known ground truth (tests and benchmarks).

Board corners are projected through a known camera (``cv2.projectPoints``, with distortion),
Gaussian pixel noise is added, and the board pose is measured back with PnP, so the noise on
``cam_T_board`` has the structure of real data (depth and tilt errors larger than lateral ones).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from eye_in_hand.core.camera import CameraModel, StereoRig
from eye_in_hand.core.transforms import from_rotvec, invert_many

from .observe import board_pose_pnp
from .samples import CameraView, CornerObservation, HandEyeSample
from .solvers import SETUPS

__all__ = ["SyntheticProblem", "default_camera", "board_corners", "view_poses",
           "make_problem"]


@dataclass(frozen=True)
class SyntheticProblem:
    """A synthetic hand-eye problem.

    Attributes:
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.
        X: true hand-eye transform, shape (4, 4).
        Y: true board pose in its fixed frame, shape (4, 4).
        samples: noisy samples (PnP board poses and corner observations).
        views: the rig's cameras.
        true_cam_T_board: noise-free board poses, shape (N, 4, 4).
        true_base_T_ee: noise-free robot poses, shape (N, 4, 4).
    """

    setup: str
    X: np.ndarray
    Y: np.ndarray
    samples: list[HandEyeSample]
    views: list[CameraView]
    true_cam_T_board: np.ndarray
    true_base_T_ee: np.ndarray


def default_camera(name: str = "left") -> CameraModel:
    """A 1280x800 camera with mild plumb_bob distortion."""
    K = np.array([[900.0, 0.0, 640.0], [0.0, 900.0, 400.0], [0.0, 0.0, 1.0]])
    return CameraModel(K=K, dist=np.array([-0.12, 0.08, 0.0005, -0.0003, 0.0]), width=1280,
                       height=800, name=name)


def board_corners(cols: int = 9, rows: int = 6, square: float = 0.025) -> np.ndarray:
    """Inner corners in the board frame, OpenCV order, shape (cols*rows, 3)."""
    grid = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * square
    return np.hstack([grid, np.zeros((grid.shape[0], 1))])


def view_poses(n: int, rng: np.random.Generator, *, center: np.ndarray,
               distance: tuple[float, float] = (0.35, 0.6), max_tilt_deg: float = 40.0,
               max_roll_deg: float = 180.0) -> np.ndarray:
    """Camera poses looking at a board (from its -z side): ``cam_T_board``, shape (n, 4, 4)."""
    out = np.zeros((n, 4, 4))
    for i in range(n):
        tilt = np.radians(max_tilt_deg) * np.sqrt(rng.uniform())
        az = rng.uniform(0, 2 * np.pi)
        direction = np.array([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az),
                              -np.cos(tilt)])
        pos = center + rng.uniform(*distance) * direction
        target = center + rng.normal(scale=0.01, size=3)
        z = (target - pos) / np.linalg.norm(target - pos)
        x0 = np.cross([0.0, 1.0, 0.0], z)
        x0 /= np.linalg.norm(x0)
        y0 = np.cross(z, x0)
        roll = rng.uniform(-np.radians(max_roll_deg), np.radians(max_roll_deg))
        x = np.cos(roll) * x0 + np.sin(roll) * y0
        y = np.cross(z, x)
        board_T_cam = np.eye(4)
        board_T_cam[:3, :3] = np.stack([x, y, z], axis=1)
        board_T_cam[:3, 3] = pos
        out[i] = np.linalg.inv(board_T_cam)
    return out


def make_problem(n: int = 15, *, setup: str = "eye_in_hand", seed: int = 0,
                 noise_px: float = 0.5, stereo: bool = False, robot_noise_mm: float = 0.0,
                 robot_noise_deg: float = 0.0, camera: CameraModel | None = None,
                 board: tuple[int, int, float] = (9, 6, 0.025)) -> SyntheticProblem:
    """Generate a hand-eye problem whose every board view lies fully inside the image(s).

    Args:
        n: number of samples.
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.
        seed: random seed.
        noise_px: Gaussian corner noise (px, per coordinate).
        stereo: add a right camera (6 cm baseline) with its own corner observations.
        robot_noise_mm, robot_noise_deg: Gaussian noise on the reported robot poses.
        camera: the (left) camera; :func:`default_camera` by default.
        board: (cols, rows, square_m).

    Returns:
        The problem.
    """
    if setup not in SETUPS:
        raise ValueError(f"setup must be one of {SETUPS}")
    rng = np.random.default_rng(seed)
    cam = camera or default_camera()
    obj = board_corners(*board)
    center = obj.mean(axis=0)
    if setup == "eye_in_hand":
        X = from_rotvec([0.1, -0.2, 0.15], [0.04, -0.06, 0.09])          # ee_T_cam
        Y = from_rotvec([np.pi, 0.0, 0.3], [0.55, 0.1, 0.02])            # base_T_board
    else:
        X = from_rotvec([2.2, 0.3, -0.4], [0.9, -0.3, 0.8])              # base_T_cam
        Y = from_rotvec([0.2, np.pi - 0.2, 0.1], [0.0, 0.02, 0.12])      # ee_T_board
    views = [CameraView("left", cam)]
    if stereo:
        R = Rotation.from_rotvec([0.0, -0.03, 0.0]).as_matrix()
        right = CameraModel(K=cam.K, dist=cam.dist, width=cam.width, height=cam.height,
                            name="right")
        rig = StereoRig(left=cam, right=right, R=R, T=np.array([-0.06, 0.0, 0.0]))
        views.append(CameraView("right", right, rig.right_T_left))
    samples: list[HandEyeSample] = []
    C_true, B_true = [], []
    while len(samples) < n:
        C = view_poses(1, rng, center=center)[0]
        pix = []
        for v in views:
            T = v.view_T_cam @ C
            p = v.model.project(obj @ T[:3, :3].T + T[:3, 3])
            pix.append(p)
        if any(np.any(~np.isfinite(p)) or np.any(p < 10) or np.any(p[:, 0] > cam.width - 10)
               or np.any(p[:, 1] > cam.height - 10) for p in pix):
            continue
        G = Y @ invert_many(C) @ invert_many(X)
        bte = G if setup == "eye_in_hand" else invert_many(G)
        noisy = bte.copy()
        if robot_noise_mm or robot_noise_deg:
            noisy = bte @ from_rotvec(rng.normal(scale=np.radians(robot_noise_deg), size=3),
                                      rng.normal(scale=robot_noise_mm / 1000.0, size=3))
        obs = tuple(CornerObservation(v.name, obj, p + rng.normal(scale=noise_px, size=p.shape))
                    for v, p in zip(views, pix, strict=True))
        C_meas, _ = board_pose_pnp(cam, obj, obs[0].image_points)
        if noise_px == 0:
            C_meas = C.copy()
        samples.append(HandEyeSample(f"s{len(samples):02d}", noisy, C_meas, obs))
        C_true.append(C)
        B_true.append(bte)
    return SyntheticProblem(setup, X, Y, samples, views, np.stack(C_true), np.stack(B_true))
