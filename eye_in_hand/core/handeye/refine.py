"""Joint nonlinear refinement of the hand-eye transform X and the board pose Y.

Model (see :mod:`.solvers`): ``cam_T_board[i] = inv(X) @ inv(G[i]) @ Y`` with ``G[i]`` the
robot pose as the solvers take it (``base_T_ee`` eye-in-hand, its inverse eye-to-hand) and ``Y``
the board pose in its fixed frame (``base_T_board`` eye-in-hand, ``ee_T_board`` eye-to-hand).

Parameters: 12 numbers, ``[t_X, dr_X, t_Y, dr_Y]``, each pose as its translation (metres) and a
rotation vector (radians) applied on the left of the start rotation, ``R = exp([dr]x) R0``.
The covariance of X is reported in that order (``x y z rx ry rz``), the convention of
``hand_eye.yaml`` and of :mod:`eye_in_hand.core.localization`.

Two cost functions, both minimised with ``scipy.optimize.least_squares`` (trust region
reflective with the LSMR sub-problem solver, which avoids a dense SVD per iteration; robust
``soft_l1`` loss):

* **reprojection** (images available): the pixel error of every board corner in every sample,
  in every camera of the rig (left and right for a stereo rig, through ``view_T_cam``);
* **pose space** (pose pairs only, no corners): the difference between the predicted and the
  measured ``cam_T_board`` of every sample, as a rotation vector and a translation, each scaled
  by a robust estimate of its own noise level so the two are commensurate.

The covariance is ``s^2 (J^T J)^-1`` at the solution with ``s^2`` the residual variance
(``2 cost / (m - 12)``), i.e. the Gauss-Newton approximation scaled by the observed noise.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from eye_in_hand.core.transforms import invert_many
from eye_in_hand.errors import HandEyeError

from .samples import CameraView, HandEyeSample, corner_blocks
from .solvers import gripper_poses

__all__ = [
    "RefinementResult",
    "refine_reprojection",
    "refine_pose_space",
    "reprojection_errors",
    "perturb",
    "project_points",
]


@dataclass(frozen=True)
class RefinementResult:
    """Outcome of a joint refinement.

    Attributes:
        X: refined hand-eye transform, shape (4, 4).
        Y: refined board pose in its fixed frame, shape (4, 4).
        covariance: covariance of X, shape (6, 6), order ``x y z rx ry rz`` (m, rad; rotation
            perturbation on the left, in the parent frame).
        covariance_full: covariance of all 12 parameters (X then Y), shape (12, 12).
        sigma: residual standard deviation (px for reprojection, unitless for pose space).
        cost: final robust cost.
        nfev: number of function evaluations.
        space: ``"reprojection"`` or ``"pose"``.
    """

    X: np.ndarray
    Y: np.ndarray
    covariance: np.ndarray
    covariance_full: np.ndarray
    sigma: float
    cost: float
    nfev: int
    space: str


def perturb(T0: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``[exp([dr]x) R0 | t]`` from ``p = [t (3), dr (3)]``, shape (4, 4)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(p[3:6]).as_matrix() @ T0[:3, :3]
    T[:3, 3] = p[:3]
    return T


def _start(T: np.ndarray) -> np.ndarray:
    return np.concatenate([T[:3, 3], np.zeros(3)])


def _covariance(res: Any, m: int) -> tuple[np.ndarray, float]:
    dof = max(1, m - res.x.size)
    s2 = 2.0 * float(res.cost) / dof
    J = res.jac
    JtJ = J.T @ J
    try:
        cov = np.linalg.inv(JtJ) * s2
    except np.linalg.LinAlgError as exc:
        raise HandEyeError("refinement: the problem is singular (motions do not determine X)") \
            from exc
    return 0.5 * (cov + cov.T), float(np.sqrt(s2))


def project_points(points_cam: np.ndarray, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """OpenCV's pinhole + distortion model, vectorised (as ``cv2.projectPoints``).

    Args:
        points_cam: shape (N, 3), camera frame.
        K: shape (3, 3).
        dist: OpenCV coefficients ``k1 k2 p1 p2 [k3 [k4 k5 k6]]`` (4, 5 or 8 values).

    Returns:
        Distorted pixels, shape (N, 2).
    """
    d = np.zeros(8)
    dist = np.asarray(dist, dtype=np.float64).ravel()
    if dist.size > 8:
        if np.any(dist[8:] != 0):
            raise HandEyeError("thin-prism / tilted distortion terms are not supported")
        dist = dist[:8]
    d[:dist.size] = dist
    k1, k2, p1, p2, k3, k4, k5, k6 = d
    x = points_cam[:, 0] / points_cam[:, 2]
    y = points_cam[:, 1] / points_cam[:, 2]
    r2 = x * x + y * y
    radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    K = np.asarray(K, dtype=np.float64)
    # Like cv2.projectPoints, the skew K[0, 1] is ignored.
    return np.stack([K[0, 0] * xd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=1)


def _project(view: CameraView, cam_T_board: np.ndarray, obj: np.ndarray) -> np.ndarray:
    T = view.view_T_cam @ cam_T_board
    rvec = Rotation.from_matrix(T[:3, :3]).as_rotvec()
    px, _ = cv2.projectPoints(obj.reshape(-1, 1, 3), rvec, T[:3, 3].copy(),
                              np.asarray(view.model.K, dtype=np.float64),
                              np.asarray(view.model.dist, dtype=np.float64))
    return px.reshape(-1, 2)


def reprojection_errors(X: np.ndarray, Y: np.ndarray, samples: Sequence[HandEyeSample],
                        cameras: Sequence[CameraView], setup: str) -> list[np.ndarray]:
    """Pixel errors of every corner for a given X and Y.

    Args:
        X: hand-eye transform, shape (4, 4).
        Y: board pose in its fixed frame, shape (4, 4).
        samples: the samples with their corner observations.
        cameras: the rig's cameras.
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.

    Returns:
        One array per sample, shape (M_i, 2): projected minus detected pixels over all of
        that sample's observations (M_i = 0 when it has none).

    Raises:
        HandEyeError: an observation names a camera that is not in ``cameras``.
    """
    views = {c.name: c for c in cameras}
    G = gripper_poses(np.stack([s.base_T_ee for s in samples]), setup)
    Xi = invert_many(X)
    out = []
    for s, g in zip(samples, G, strict=True):
        C = Xi @ invert_many(g) @ Y
        errs = []
        for ob in s.observations:
            if ob.camera not in views:
                raise HandEyeError(f"sample {s.name!r}: corners from camera {ob.camera!r}, "
                                   f"but the rig has {sorted(views)}")
            errs.append(_project(views[ob.camera], C, ob.object_points) - ob.image_points)
        out.append(np.concatenate(errs) if errs else np.zeros((0, 2)))
    return out


def refine_reprojection(X0: np.ndarray, Y0: np.ndarray, samples: Sequence[HandEyeSample],
                        cameras: Sequence[CameraView], setup: str, *,
                        f_scale_px: float = 3.0, max_nfev: int = 200) -> RefinementResult:
    """Refine X and Y by minimising the corner reprojection error over all samples and cameras.

    Args:
        X0: start hand-eye transform (the best closed form), shape (4, 4).
        Y0: start board pose in its fixed frame, shape (4, 4).
        samples: samples with corner observations (validated).
        cameras: the rig's cameras (one for mono, left and right for stereo).
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.
        f_scale_px: the robust loss's inlier scale, pixels (residuals well above it count
            linearly, not quadratically).
        max_nfev: evaluation budget.

    Returns:
        The refinement result (``space = "reprojection"``).

    Raises:
        HandEyeError: no corners, a camera missing from ``cameras``, or a singular problem.
    """
    n_obs = sum(ob.object_points.shape[0] for s in samples for ob in s.observations)
    if n_obs == 0:
        raise HandEyeError("reprojection refinement needs corner observations; use "
                           "refine_pose_space for pose pairs")
    blocks = corner_blocks(samples, cameras)   # per camera, vectorised model
    Ginv = invert_many(gripper_poses(np.stack([s.base_T_ee for s in samples]), setup))

    def residuals(p: np.ndarray) -> np.ndarray:
        Xi = invert_many(perturb(X0, p[:6]))
        Y = perturb(Y0, p[6:])
        C = Xi @ Ginv @ Y                                   # (N, 4, 4) cam_T_board
        out = []
        for cam, idx, obj, img in blocks:
            T = cam.view_T_cam @ C
            pts = np.einsum("kij,kj->ki", T[idx, :3, :3], obj) + T[idx, :3, 3]
            out.append((project_points(pts, cam.model.K, cam.model.dist) - img).ravel())
        return np.concatenate(out)

    p0 = np.concatenate([_start(X0), _start(Y0)])
    res = least_squares(residuals, p0, loss="soft_l1", f_scale=float(f_scale_px),
                        x_scale="jac", max_nfev=max_nfev, method="trf", tr_solver="lsmr")
    cov, sigma = _covariance(res, res.fun.size)
    return RefinementResult(perturb(X0, res.x[:6]), perturb(Y0, res.x[6:]), cov[:6, :6], cov,
                            sigma, float(res.cost), int(res.nfev), "reprojection")


def pose_residual_scales(X: np.ndarray, Y: np.ndarray, base_T_ee: np.ndarray,
                         cam_T_board: np.ndarray, setup: str) -> tuple[float, float]:
    """Robust noise levels (rad, m) of the measured board poses around the model prediction."""
    r, t = _pose_errors(X, Y, invert_many(gripper_poses(base_T_ee, setup)), cam_T_board)
    sr = 1.4826 * float(np.median(np.linalg.norm(r, axis=1))) / np.sqrt(3.0)
    st = 1.4826 * float(np.median(np.linalg.norm(t, axis=1))) / np.sqrt(3.0)
    return max(sr, 1e-9), max(st, 1e-9)


def _pose_errors(X: np.ndarray, Y: np.ndarray, Ginv: np.ndarray,
                 C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pred = invert_many(X) @ Ginv @ Y
    dR = np.einsum("kji,kjl->kil", C[:, :3, :3], pred[:, :3, :3])
    return Rotation.from_matrix(dR).as_rotvec(), pred[:, :3, 3] - C[:, :3, 3]


def refine_pose_space(X0: np.ndarray, Y0: np.ndarray, base_T_ee: np.ndarray,
                      cam_T_board: np.ndarray, setup: str, *,
                      scales: tuple[float, float] | None = None,
                      f_scale: float = 2.0, max_nfev: int = 200) -> RefinementResult:
    """Refine X and Y in pose space (for pose pairs without corner observations).

    Args:
        X0: start hand-eye transform, shape (4, 4).
        Y0: start board pose in its fixed frame, shape (4, 4).
        base_T_ee: robot poses, shape (N, 4, 4).
        cam_T_board: measured board poses, shape (N, 4, 4).
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.
        scales: noise levels ``(rotation rad, translation m)`` that normalise the residuals;
            estimated robustly from the start solution when None.
        f_scale: robust loss scale in units of those noise levels.
        max_nfev: evaluation budget.

    Returns:
        The refinement result (``space = "pose"``; ``sigma`` is unitless, about 1 when the
        scales are right).
    """
    base_T_ee = np.asarray(base_T_ee, dtype=np.float64)
    C = np.asarray(cam_T_board, dtype=np.float64)
    sr, st = scales if scales is not None else pose_residual_scales(X0, Y0, base_T_ee, C, setup)
    Ginv = invert_many(gripper_poses(base_T_ee, setup))

    def residuals(p: np.ndarray) -> np.ndarray:
        r, t = _pose_errors(perturb(X0, p[:6]), perturb(Y0, p[6:]), Ginv, C)
        return np.concatenate([r / sr, t / st], axis=1).ravel()

    p0 = np.concatenate([_start(X0), _start(Y0)])
    res = least_squares(residuals, p0, loss="soft_l1", f_scale=float(f_scale), x_scale="jac",
                        max_nfev=max_nfev, method="trf", tr_solver="lsmr")
    cov, sigma = _covariance(res, res.fun.size)
    return RefinementResult(perturb(X0, res.x[:6]), perturb(Y0, res.x[6:]), cov[:6, :6], cov,
                            sigma, float(res.cost), int(res.nfev), "pose")
