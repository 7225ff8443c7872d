"""The error budget of a hand-eye calibration: where the held-out error comes from.

Every figure is an RMS over the samples of a 3-d distance (mm) at the board's origin in the
fixed frame (the robot base, eye-in-hand), the point of the held-out figures of
:mod:`.select`, so that the parts add in squares to the held-out error ``h``:

* ``camera_mm`` (``c``): the board's measurement error from its corners: each view's PnP
  covariance at the corners' pixel noise (the RMS PnP residual over the views: corner noise
  and whatever of the intrinsics a single view cannot absorb), propagated to the origin;
* ``robot_mm``: what else scatters from pose to pose in the fitted samples (the robot's
  per-pose error, and any intrinsics or board error that changes with distance and angle):
  ``sqrt(r^2 - c^2)`` with ``r`` the in-sample board scatter, corrected for the 12 fitted
  parameters of X and Y (``r^2 = mean(dev^2) n / (n - 2)``);
* ``estimate_mm``: the error of the estimate itself at poses it was not fitted on (the
  uncertainty of X and Y, and of the robot model): ``sqrt(h^2 - r^2)``;
* ``robot_systematic_mm`` (shown beside the parts): the pose-dependent robot error the
  systematic model found (the RMS at the board origin of its correction over the samples);
  with ``refined_systematic`` selected it is corrected, otherwise it is inside ``robot_mm``
  and ``estimate_mm``.

``largest`` names the largest part and ``advice`` what to do about it: recalibrate the camera
(camera), model or calibrate the robot (robot), take more poses (estimate).
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .observe import board_pose_pnp
from .samples import CameraView, HandEyeSample
from .select import _centre_variance

__all__ = ["error_budget"]

_ADVICE = {
    "camera_mm": "the camera dominates: recalibrate the intrinsics, with sharper images",
    "robot_mm": "the per-pose scatter dominates: the robot's pose error (with "
                "--robot-model per_pose try the default, systematic; check that the arm is "
                "still at each capture) or an intrinsics or board error that changes with "
                "distance and angle",
    "estimate_mm": "the estimate's own uncertainty dominates: take more poses with larger "
                   "rotations",
}


def error_budget(samples: Sequence[HandEyeSample], cameras: Sequence[CameraView] | None,
                 setup: str, Y: np.ndarray, board_dev_mm: np.ndarray,
                 held_out_mm: np.ndarray,
                 systematic_correction: np.ndarray | None = None) -> dict[str, Any]:
    """The parts of the held-out error (see the module docstring).

    Args:
        samples: the samples used (their poses corrected when the systematic model is
            selected).
        cameras: the rig's cameras (the camera part needs them and corners), or None.
        setup: ``"eye_in_hand"`` or ``"eye_to_hand"``.
        Y: the selected board pose in its fixed frame, shape (4, 4).
        board_dev_mm: in-sample board deviation of each sample, shape (N,).
        held_out_mm: held-out board deviation of each sample, shape (N,).
        systematic_correction: the systematic model's correction of each sample's pose,
            ``[t, rotvec]`` in the flange frame, shape (N, 6), or None.

    Returns:
        Plain data: the parts (mm), ``held_out_mm``, ``largest`` and ``advice``.
    """
    n = len(samples)
    h2 = float(np.mean(np.square(held_out_mm)))
    r2 = float(np.mean(np.square(board_dev_mm))) * n / max(n - 2, 1)
    c2 = 0.0
    use_corners = bool(cameras) and all(len(s.observations) > 0 for s in samples)
    if use_corners:
        assert cameras is not None
        views = {v.name: v for v in cameras}
        pnp = [board_pose_pnp(views[s.observations[0].camera].model,
                              s.observations[0].object_points,
                              s.observations[0].image_points)[1] for s in samples]
        px = float(np.sqrt(np.mean(np.square(pnp))))
        c2 = 1e6 * float(np.mean([_centre_variance(s, cameras, px, np.zeros(3))
                                  for s in samples]))
    parts = {"camera_mm": float(np.sqrt(c2)) if use_corners else float("nan"),
             "robot_mm": float(np.sqrt(max(0.0, r2 - c2))),
             "estimate_mm": float(np.sqrt(max(0.0, h2 - r2)))}
    out: dict[str, Any] = {k: (None if not np.isfinite(v) else round(v, 4))
                           for k, v in parts.items()}
    finite = {k: v for k, v in parts.items() if np.isfinite(v)}
    out["largest"] = max(finite, key=lambda k: finite[k])
    out["advice"] = _ADVICE[out["largest"]]
    out["held_out_mm"] = round(float(np.sqrt(h2)), 4)
    if systematic_correction is not None:
        d = np.asarray(systematic_correction)
        lev = []
        for s in samples:
            if setup == "eye_in_hand":
                lev.append(s.base_T_ee[:3, :3].T @ (Y[:3, 3] - s.base_T_ee[:3, 3]))
            else:
                lev.append(Y[:3, 3])
        moved = d[:, :3] + np.cross(d[:, 3:], np.asarray(lev))
        out["robot_systematic_mm"] = round(1000.0 * float(np.sqrt(np.mean(np.sum(
            moved ** 2, axis=1)))), 4)
    else:
        out["robot_systematic_mm"] = None
    return out
